//! Native refinement time per frame on the views the page's turntable flies (`#…&spin=DEG`):
//! the overview orbit turned DEG degrees a frame, refined by the page's own code (`Scene`, the
//! hosted source, progressive refinement) with the whole file already inserted. For
//! BENCHMARKS.md's wasm-vs-native row (tools/bench_web.py runs both).
//!
//!     cargo run --release -p relief-web --example refine_views -- FILE.relief [FRAMES] [SPIN_DEG] [W H] [TAU]

use std::time::Instant;

use relief_web::scene::{Orbit, Scene};

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(path) = args.first() else {
        return Err("usage: refine_views FILE.relief [FRAMES] [SPIN_DEG] [W H] [TAU]".into());
    };
    let number = |i: usize, default: f64| -> Result<f64, String> {
        args.get(i).map_or(Ok(default), |v| v.parse().map_err(|_| format!("argument {i}: not a number: {v}")))
    };
    let (frames, spin, w, h, tau) = (
        number(1, 120.0)? as usize,
        number(2, 2.0)?,
        number(3, 960.0)? as u32,
        number(4, 540.0)? as u32,
        number(5, 2.0)?,
    );
    let bytes = std::fs::read(path).map_err(|e| format!("{path}: {e}"))?;
    let mut scene = Scene::open(path, bytes.len() as u64, &bytes).map_err(|e| e.to_string())?;
    scene.options.tolerance_px = tau;
    let mut orbit = Orbit::overview(scene.terrain(), 1.0);
    let mut ms = Vec::with_capacity(frames);
    let mut triangles = Vec::with_capacity(frames);
    for _ in 0..frames {
        // As the page: the turn comes before each frame's refinement.
        orbit.yaw_deg = (orbit.yaw_deg + spin).rem_euclid(360.0);
        let camera = orbit.camera(w, h).map_err(|e| e.to_string())?;
        let t = Instant::now();
        let frame = scene.refine(&camera).map_err(|e| e.to_string())?;
        ms.push(t.elapsed().as_secs_f64() * 1e3);
        if !frame.complete() {
            return Err("a frame missed records though the whole file was inserted".into());
        }
        triangles.push(scene.triangles());
    }
    let mean = ms.iter().sum::<f64>() / ms.len().max(1) as f64;
    ms.sort_by(f64::total_cmp);
    triangles.sort_unstable();
    println!(
        "{{\"frames\": {frames}, \"refine_ms_median\": {:.4}, \"refine_ms_mean\": {mean:.4}, \"triangles_median\": {}}}",
        ms[ms.len() / 2],
        triangles[triangles.len() / 2]
    );
    Ok(())
}
