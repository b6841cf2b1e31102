//! Elegoo GOO through the `goo` crate.
//!
//! `goo::GooFile::deserialize` checks the magic tags, delimiters and the
//! ending string; this module adds what it leaves out: the layer-content
//! offset field, that the file ends where the last record does, each layer's
//! checksum, and that the decoded runs cover exactly x_res x y_res pixels.
//!
//! Output: header fields (`version`, `x_resolution`, `y_resolution`,
//! `layer_count`, sizes, exposure, lift and retract settings, `printing_time`,
//! `total_volume`, `grey_scale_level`, ...) and `layers`: per layer
//! `position_z`, `exposure`, lift and retract distances and speeds, `checksum_ok`, `pixels`
//! (sum of run lengths), `lit` (pixels > 0), `solid` (pixels >= 128),
//! `grey_sum` (sum of the pixel values), `fnv1a64` (FNV-1a 64 of the decoded
//! row-major 8-bit image, as 16 hex digits) and `ok` (checksum matches and
//! `pixels == x_res * y_res`).

use goo::{GooFile, LayerDecoder};

use crate::json::{self, Obj};

const HEADER_SIZE: usize = 195_477;
const OFFSET_FIELD: usize = 195_470;
const ENDING_LEN: usize = 11;
/// Layer record bytes besides the RLE payload: u16 + 15 f32 + u16 + CRLF +
/// u32 length + 0x55 + checksum + CRLF.
const RECORD_OVERHEAD: usize = 2 + 15 * 4 + 2 + 2 + 4 + 1 + 1 + 2;

fn text<T: std::fmt::Debug>(s: &T) -> String {
    let d = format!("{:?}", s);
    d.trim_matches('"').to_string()
}

pub fn report(data: &[u8]) -> Result<String, String> {
    let file = GooFile::deserialize(data).map_err(|e| format!("goo: {}", e))?;
    let h = &file.header;
    if data.len() < HEADER_SIZE {
        return Err(format!("goo: file is {} bytes, shorter than the header", data.len()));
    }
    let off = u32::from_be_bytes([
        data[OFFSET_FIELD],
        data[OFFSET_FIELD + 1],
        data[OFFSET_FIELD + 2],
        data[OFFSET_FIELD + 3],
    ]) as usize;
    let expected: usize = HEADER_SIZE
        + file.layers.iter().map(|l| RECORD_OVERHEAD + l.data.len()).sum::<usize>()
        + ENDING_LEN;
    let res = h.x_resolution as u64 * h.y_resolution as u64;

    let mut layers = Vec::new();
    let mut all_ok = true;
    for layer in &file.layers {
        let dec = LayerDecoder::new(&layer.data);
        let checksum_ok = dec.checksum() == layer.checksum;
        let (mut pixels, mut lit, mut solid, mut grey) = (0u64, 0u64, 0u64, 0u64);
        let mut hash: u64 = 0xcbf29ce484222325;
        for run in dec {
            pixels += run.length;
            if run.value > 0 {
                lit += run.length;
            }
            if run.value >= 128 {
                solid += run.length;
            }
            grey += run.length * run.value as u64;
            if pixels <= res {
                for _ in 0..run.length {
                    hash ^= run.value as u64;
                    hash = hash.wrapping_mul(0x100000001b3);
                }
            }
        }
        let ok = checksum_ok && pixels == res;
        all_ok &= ok;
        layers.push(
            Obj::new()
                .num("position_z", layer.layer_position_z as f64)
                .num("exposure", layer.layer_exposure_time as f64)
                .num("lift_distance", layer.lift_distance as f64)
                .num("lift_speed", layer.lift_speed as f64)
                .num("retract_distance", layer.retract_distance as f64)
                .num("retract_speed", layer.retract_speed as f64)
                .int("light_pwm", layer.light_pwm as i64)
                .boolean("checksum_ok", checksum_ok)
                .int("pixels", pixels as i64)
                .int("lit", lit as i64)
                .int("solid", solid as i64)
                .int("grey_sum", grey as i64)
                .str("fnv1a64", &format!("{:016x}", hash))
                .int("payload_bytes", layer.data.len() as i64)
                .boolean("ok", ok)
                .end(),
        );
    }
    let out = Obj::new()
        .str("format", "goo")
        .str("version", &text(&h.version))
        .str("software_info", &text(&h.software_info))
        .str("printer_name", &text(&h.printer_name))
        .int("x_resolution", h.x_resolution as i64)
        .int("y_resolution", h.y_resolution as i64)
        .boolean("x_mirror", h.x_mirror)
        .boolean("y_mirror", h.y_mirror)
        .num("x_size", h.x_size as f64)
        .num("y_size", h.y_size as f64)
        .num("z_size", h.z_size as f64)
        .num("layer_thickness", h.layer_thickness as f64)
        .int("layer_count", h.layer_count as i64)
        .num("exposure_time", h.exposure_time as f64)
        .num("bottom_exposure_time", h.bottom_exposure_time as f64)
        .int("bottom_layers", h.bottom_layers as i64)
        .num("bottom_lift_distance", h.bottom_lift_distance as f64)
        .num("bottom_lift_speed", h.bottom_lift_speed as f64)
        .num("lift_distance", h.lift_distance as f64)
        .num("lift_speed", h.lift_speed as f64)
        .num("bottom_retract_distance", h.bottom_retract_distance as f64)
        .num("bottom_retract_speed", h.bottom_retract_speed as f64)
        .num("retract_distance", h.retract_distance as f64)
        .num("retract_speed", h.retract_speed as f64)
        .int("bottom_light_pwm", h.bottom_light_pwm as i64)
        .int("light_pwm", h.light_pwm as i64)
        .int("printing_time", h.printing_time as i64)
        .num("total_volume", h.total_volume as f64)
        .int("transition_layers", h.transition_layers as i64)
        .int("anti_aliasing_level", h.anti_aliasing_level as i64)
        .boolean("grey_scale_level", h.grey_scale_level)
        .int("layer_content_offset", off as i64)
        .boolean("offset_ok", off == HEADER_SIZE)
        .int("file_size", data.len() as i64)
        .boolean("size_ok", expected == data.len())
        .boolean("layers_ok", all_ok)
        .raw("layers", &json::array(layers))
        .end();
    Ok(out)
}
