//! Binary CLI (Common Layer Interface v2.0) through `colain`.
//!
//! Output (one JSON object):
//! `variant` ("long" or "short"), `units` (mm per coordinate unit),
//! `version`, `aligned`, `header_layers` (from `$$LAYERS`, or null) and
//! `layers`: for each layer `z` (mm = raw height x units), `z_raw`,
//! `polylines`, `outer` / `holes` / `open` (direction 1 / 0 / 2),
//! `vertex_counts` and `dirs` per polyline, `vertices` (total), `closed`
//! (every non-open polyline repeats its first point last), `area` (mm², the
//! sum of the shoelace areas: counter-clockwise positive, so outer minus
//! holes for a well-formed file), `dir_mismatch` (closed polylines whose
//! orientation disagrees with their direction flag), `hatches`.

use colain::clitype::{CLIType, LongCLI, ShortCLI};
use colain::{Error, CLI};

use crate::json::{self, Obj};

pub fn report(data: &[u8]) -> Result<String, String> {
    match CLI::<LongCLI>::new(data) {
        Ok(model) => Ok(describe(&model, "long")),
        Err(Error::TypeMismatch) => match CLI::<ShortCLI>::new(data) {
            Ok(model) => Ok(describe(&model, "short")),
            Err(e) => Err(format!("colain: {}", e)),
        },
        Err(e) => Err(format!("colain: {}", e)),
    }
}

/// Reads element `i` of a slice that `colain` built over the raw file bytes
/// (the data need not be aligned for its type).
fn at<C: Copy>(s: &[C], i: usize) -> C {
    assert!(i < s.len());
    unsafe { s.as_ptr().add(i).read_unaligned() }
}

fn describe<'a, T>(model: &'a CLI<'a, T>, variant: &str) -> String
where
    T: CLIType,
    T::Coord: Into<f64>,
    T::Meta: Into<i64>,
{
    let h = model.header();
    let u = h.units;
    let mut layers = Vec::new();
    for layer in model.iter() {
        let z_raw: f64 = layer.height().into();
        let (mut outer, mut holes, mut open, mut mismatch) = (0i64, 0i64, 0i64, 0i64);
        let mut counts = Vec::new();
        let mut dirs = Vec::new();
        let mut total = 0i64;
        let mut closed = true;
        let mut area = 0.0f64;
        for lp in layer.iter_loops() {
            let dir: i64 = lp.dir().into();
            let pts = lp.points();
            let n = pts.len() / 2;
            counts.push(n.to_string());
            dirs.push(dir.to_string());
            total += n as i64;
            match dir {
                1 => outer += 1,
                0 => holes += 1,
                _ => open += 1,
            }
            if dir == 2 || n == 0 {
                continue;
            }
            let x = |k: usize| -> f64 { at(pts, 2 * k).into() };
            let y = |k: usize| -> f64 { at(pts, 2 * k + 1).into() };
            if x(0) != x(n - 1) || y(0) != y(n - 1) {
                closed = false;
            }
            // Shoelace over the closed ring (the repeated last point adds 0).
            let mut a = 0.0f64;
            for k in 0..n {
                let j = (k + 1) % n;
                a += x(k) * y(j) - x(j) * y(k);
            }
            let a = 0.5 * a * u * u;
            area += a;
            if (dir == 1 && a <= 0.0) || (dir == 0 && a >= 0.0) {
                mismatch += 1;
            }
        }
        let o = Obj::new()
            .num("z", z_raw * u)
            .num("z_raw", z_raw)
            .int("polylines", counts.len() as i64)
            .int("outer", outer)
            .int("holes", holes)
            .int("open", open)
            .raw("vertex_counts", &json::array(counts))
            .raw("dirs", &json::array(dirs))
            .int("vertices", total)
            .boolean("closed", closed)
            .num("area", area)
            .int("dir_mismatch", mismatch)
            .int("hatches", layer.iter_hatches().count() as i64);
        layers.push(o.end());
    }
    let header_layers = match h.layers {
        Some(n) => n.to_string(),
        None => "null".to_string(),
    };
    Obj::new()
        .str("format", "cli")
        .str("variant", variant)
        .boolean("binary", h.binary)
        .num("units", h.units)
        .num("version", h.version as f64)
        .boolean("aligned", h.aligned)
        .raw("header_layers", &header_layers)
        .int("layer_count", layers.len() as i64)
        .raw("layers", &json::array(layers))
        .end()
}
