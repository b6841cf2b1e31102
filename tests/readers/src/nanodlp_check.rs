//! NanoDLP (`.nanodlp`) through the `msla_format` crate's `nanodlp` module.
//!
//! `msla_format::nanodlp::File::deserialize` opens the zip and parses
//! `meta.json` (optional), `info.json`, `plate.json`, `profile.json` and
//! `options.json` (else `slicer.json`) with its serde structs, so every field
//! must have the type the contract gives it (a length written as `50` where a
//! float is expected is rejected); it decodes `3d.png` and reads `1.png` ...
//! `N.png` for the N entries of `info.json`. Each layer is decoded with the
//! crate's `LayerDecoder` (PNG to 8-bit RGB; every byte one display pixel).
//!
//! This module adds what the crate leaves to its caller: the decoded layer
//! covers exactly `PWidth x PHeight` pixels, the PNG is `PWidth / 3` RGB
//! pixels wide, and the layer counts of `info.json`, `plate.json` and
//! `options.json` agree.
//!
//! Output: `meta`, `options`, `profile` and `plate` fields as parsed,
//! `preview` size, `layer_count` (entries of `info.json`), `layers_ok`, and
//! `layers`: per layer `png_width`, `png_height`, `pixels` (sum of run
//! lengths), `lit` (> 0), `solid` (>= 128), `grey_sum`, `weighted_sum`
//! (sum of value x (row-major index + 1), wrapping mod 2^64: a
//! position-sensitive checksum), the parsed `info` entry and `ok`.

use std::io::Cursor;

use msla_format::nanodlp::{File, LayerDecoder};

use crate::json::{self, Obj};

/// Sum of (i + 1) for i in start..start + len, wrapping mod 2^64.
fn index_sum(start: u64, len: u64) -> u64 {
    // len (start + 1) + len (len - 1) / 2, halving the even factor first.
    let tri = if len % 2 == 0 {
        (len / 2).wrapping_mul(len.wrapping_sub(1))
    } else {
        len.wrapping_mul(len.wrapping_sub(1) / 2)
    };
    len.wrapping_mul(start.wrapping_add(1)).wrapping_add(tri)
}

pub fn report(data: &[u8]) -> Result<String, String> {
    let file = File::deserialize(Cursor::new(data)).map_err(|e| format!("msla_format: {:#}", e))?;
    let o = &file.options;
    let res = o.p_width as u64 * o.p_height as u64;

    let mut layers = Vec::new();
    let mut all_ok = true;
    for (k, (png, info)) in file.layers.iter().zip(file.layer_info.iter()).enumerate() {
        let dec = LayerDecoder::new(png);
        let (mut pixels, mut lit, mut solid, mut grey, mut weighted) = (0u64, 0u64, 0u64, 0u64, 0u64);
        for run in dec.runs() {
            let v = run.value as u64;
            if v > 0 {
                lit += run.length;
            }
            if v >= 128 {
                solid += run.length;
            }
            grey += run.length * v;
            weighted = weighted.wrapping_add(v.wrapping_mul(index_sum(pixels, run.length)));
            pixels += run.length;
        }
        let img = dec.into_inner();
        let (w, h) = (img.width(), img.height());
        let ok = pixels == res && 3 * w == o.p_width && h == o.p_height;
        all_ok &= ok;
        let info_doc = Obj::new()
            .num("total_solid_area", info.total_solid_area.raw() as f64)
            .num("largest_area", info.largest_area.raw() as f64)
            .num("smallest_area", info.smallest_area.raw() as f64)
            .int("min_x", info.min_x as i64)
            .int("min_y", info.min_y as i64)
            .int("max_x", info.max_x as i64)
            .int("max_y", info.max_y as i64)
            .int("area_count", info.area_count as i64)
            .end();
        layers.push(
            Obj::new()
                .int("index", k as i64 + 1)
                .int("png_width", w as i64)
                .int("png_height", h as i64)
                .int("pixels", pixels as i64)
                .int("lit", lit as i64)
                .int("solid", solid as i64)
                .int("grey_sum", grey as i64)
                .str("weighted_sum", &weighted.to_string())
                .raw("info", &info_doc)
                .boolean("ok", ok)
                .end(),
        );
    }
    let n = file.layer_info.len() as i64;
    let counts_ok = file.plate.layers_count as i64 == n && o.layer_count as i64 == n;

    let m = &file.meta;
    let meta = Obj::new()
        .int("format_version", m.format_version as i64)
        .str("distro", &m.distro)
        .str("program", &m.program)
        .str("version", &m.version)
        .boolean("profile", m.profile)
        .end();
    let options = Obj::new()
        .int("p_width", o.p_width as i64)
        .int("p_height", o.p_height as i64)
        .num("thickness_um", o.thickness.raw() as f64)
        .int("support_depth", o.support_depth as i64)
        .int("support_layer_number", o.support_layer_number as i64)
        .num("x_pixel_size", o.x_pixel_size.raw() as f64)
        .num("y_pixel_size", o.y_pixel_size.raw() as f64)
        .num("x_res_um", o.x_res.raw() as f64)
        .num("y_res_um", o.y_res.raw() as f64)
        .int("x_offset", o.x_offset as i64)
        .int("y_offset", o.y_offset as i64)
        .int("anti_alias", o.anti_alias as i64)
        .int("image_mirror", o.image_mirror as i64)
        .int("display_controller", o.display_controller as i64)
        .int("layer_count", o.layer_count as i64)
        .str("fill_color", &o.fill_color)
        .str("blank_color", &o.blank_color)
        .end();
    let p = &file.profile;
    let profile = Obj::new()
        .str("title", &p.title)
        .num("depth_um", p.depth.raw() as f64)
        .num("support_depth_um", p.support_depth.raw() as f64)
        .num("cure_time", p.cure_time.raw() as f64)
        .num("support_cure_time", p.support_cure_time.raw() as f64)
        .int("support_layer_number", p.support_layer_number as i64)
        .int("transitional_layer", p.transitional_layer as i64)
        .int("anti_alias", p.anti_alias as i64)
        .end();
    let pl = &file.plate;
    let plate = Obj::new()
        .int("layers_count", pl.layers_count as i64)
        .boolean("processed", pl.processed)
        .num("total_solid_area_ml", pl.total_solid_area.raw() as f64)
        .num("x_min", pl.x_min.raw() as f64)
        .num("x_max", pl.x_max.raw() as f64)
        .num("y_min", pl.y_min.raw() as f64)
        .num("y_max", pl.y_max.raw() as f64)
        .num("z_min", pl.z_min.raw() as f64)
        .num("z_max", pl.z_max.raw() as f64)
        .int("print_est", pl.print_est as i64)
        .end();
    let preview = Obj::new()
        .int("width", file.preview.width() as i64)
        .int("height", file.preview.height() as i64)
        .end();
    Ok(Obj::new()
        .str("format", "nanodlp")
        .raw("meta", &meta)
        .raw("options", &options)
        .raw("profile", &profile)
        .raw("plate", &plate)
        .raw("preview", &preview)
        .int("layer_count", n)
        .boolean("counts_ok", counts_ok)
        .boolean("layers_ok", all_ok)
        .raw("layers", &json::array(layers))
        .end())
}
