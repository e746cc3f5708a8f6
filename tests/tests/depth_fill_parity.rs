#![allow(clippy::unwrap_used)]
//! The RGB-D model's input fills invalid depth the same way in training (`train/gf/depth_fill.py`,
//! through `train/gf/data.py`) and in the node (`fill_invalid_depth`): bit for bit on a depth image
//! with random dropout, a large hole, zeros and infinities. Runs the project's test venv.

use groupforward::model::reconstruction::fill_invalid_depth;
use groupforward_tests::{root, venv_python};

/// 40×30 depth: a slanted wall at 2–4 m with a 1 m box in front, 30% of pixels dropped (NaN, 0
/// or ∞), and a 10×8 hole across the box's edge. A fixed LCG keeps it the same everywhere.
fn depth() -> (Vec<f32>, usize, usize) {
    let (width, height) = (40usize, 30usize);
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut uniform = move || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut out = Vec::with_capacity(width * height);
    for y in 0..height {
        for x in 0..width {
            let mut z = 2.0 + 2.0 * x as f32 / width as f32 + 0.01 * y as f32;
            if (12..24).contains(&x) && (10..22).contains(&y) {
                z = 1.0 + 0.003 * x as f32;
            }
            if (20..30).contains(&x) && (14..22).contains(&y) {
                z = f32::NAN;
            }
            let r = uniform();
            if r < 0.1 {
                z = f32::NAN;
            } else if r < 0.2 {
                z = 0.0;
            } else if r < 0.3 {
                z = f32::INFINITY;
            }
            out.push(z);
        }
    }
    (out, width, height)
}

#[test]
fn training_and_the_node_fill_invalid_depth_alike() {
    let (original, width, height) = depth();
    let mut rust = original.clone();
    let filled = fill_invalid_depth(&mut rust, width, height);
    let invalid = original
        .iter()
        .filter(|z| !(z.is_finite() && **z > 0.0))
        .count();
    assert_eq!(filled, invalid, "every hole is reachable from valid depth");
    assert!(rust.iter().all(|z| z.is_finite() && *z > 0.0));

    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("depth.f32");
    let bytes: Vec<u8> = original.iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(&file, bytes).unwrap();
    let script = format!(
        "import sys, numpy as np\n\
         sys.path.insert(0, {gf:?})\n\
         from depth_fill import fill_invalid_depth\n\
         d = np.fromfile({file:?}, dtype='<f4').reshape({height}, {width})\n\
         sys.stdout.buffer.write(fill_invalid_depth(d).astype('<f4').tobytes())\n",
        gf = root().join("train/gf").display().to_string(),
        file = file.display().to_string(),
    );
    let python: Vec<f32> = venv_python(&script)
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    assert_eq!(python.len(), rust.len());
    let differ = rust
        .iter()
        .zip(&python)
        .filter(|(a, b)| a.to_bits() != b.to_bits())
        .count();
    assert_eq!(differ, 0, "{differ} pixels differ");
}
