#![allow(clippy::unwrap_used)]
//! Lens distortion against OpenCV (opencv-python in the test venv, `make setup`): projection of a
//! grid of 3D points (`cv2.projectPoints`), undistortion of distorted pixels
//! (`cv2.undistortPoints` iterated to convergence) and of a textured image (`cv2.remap` over
//! `cv2.initUndistortRectifyMap`, bilinear, black outside), all with the plumb-bob model k1, k2,
//! p1, p2, k3 as ROS's CameraInfo carries it.

use std::path::Path;
use std::process::Command;

use glam::{DVec2, DVec3};
use groupforward::frame::{undistort_image, RgbImage};
use groupforward::recon::camera::{Camera, PlumbBob};

fn camera() -> Camera {
    Camera {
        distortion: PlumbBob {
            k1: -0.28,
            k2: 0.07,
            p1: 0.001,
            p2: -0.0005,
            k3: 0.01,
        },
        ..Camera::pinhole(640, 480, 500.0, 505.0, 321.5, 239.0).unwrap()
    }
}

/// Runs `script` in the test venv with `input` on stdin; returns stdout parsed as JSON.
fn python(script: &str, input: &str) -> serde_json::Value {
    let python = Path::new(env!("CARGO_MANIFEST_DIR")).join("../.venv/bin/python");
    let mut child = Command::new(&python)
        .arg("-c")
        .arg(script)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("{}: {e} (run `make setup`)", python.display()));
    use std::io::Write;
    child
        .stdin
        .take()
        .unwrap()
        .write_all(input.as_bytes())
        .unwrap();
    let output = child.wait_with_output().unwrap();
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    serde_json::from_slice(&output.stdout).unwrap()
}

const OPENCV_CAMERA: &str = "
import sys, json, numpy as np, cv2
data = json.load(sys.stdin)
c = data['camera']
K = np.array([[c['fx'], 0, c['cx']], [0, c['fy'], c['cy']], [0, 0, 1]], np.float64)
D = np.array(c['d'], np.float64)
";

fn camera_json(c: &Camera) -> serde_json::Value {
    let d = c.distortion;
    serde_json::json!({"fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy,
                       "d": [d.k1, d.k2, d.p1, d.p2, d.k3]})
}

#[test]
fn projection_and_undistortion_of_points_match_opencv() {
    let camera = camera();
    // A grid of points over the whole field of view, at several depths.
    let mut points = Vec::new();
    for ix in -6..=6 {
        for iy in -4..=4 {
            for z in [0.5, 1.7, 4.0] {
                points.push(DVec3::new(ix as f64 * 0.1 * z, iy as f64 * 0.1 * z, z));
            }
        }
    }
    let script = format!(
        "{OPENCV_CAMERA}
p = np.array(data['points'], np.float64).reshape(-1, 1, 3)
projected, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), K, D)
pixels = np.array(data['pixels'], np.float64).reshape(-1, 1, 2)
criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
undistorted = cv2.undistortPoints(pixels, K, D, None, None, None, criteria)
print(json.dumps({{'projected': projected.reshape(-1, 2).tolist(),
                  'undistorted': undistorted.reshape(-1, 2).tolist()}}))
"
    );
    let projected: Vec<DVec2> = points.iter().map(|p| camera.project(*p).unwrap()).collect();
    let input = serde_json::json!({
        "camera": camera_json(&camera),
        "points": points.iter().map(|p| p.to_array()).collect::<Vec<_>>(),
        "pixels": projected.iter().map(|p| p.to_array()).collect::<Vec<_>>(),
    });
    let opencv = python(&script, &input.to_string());
    let mut worst = (0.0f64, 0.0f64);
    for (k, p) in points.iter().enumerate() {
        let cv = &opencv["projected"][k];
        let cv = DVec2::new(cv[0].as_f64().unwrap(), cv[1].as_f64().unwrap());
        worst.0 = worst.0.max((projected[k] - cv).length());
        // Undistorting the distorted pixel gives back the pinhole ray, x/z and y/z.
        let ray = camera.ray(projected[k]);
        let cv = &opencv["undistorted"][k];
        let cv = DVec2::new(cv[0].as_f64().unwrap(), cv[1].as_f64().unwrap());
        worst.1 = worst.1.max((DVec2::new(ray.x, ray.y) - cv).length());
        assert!(
            (DVec2::new(ray.x, ray.y) - DVec2::new(p.x / p.z, p.y / p.z)).length() < 1e-9,
            "{p}"
        );
    }
    println!(
        "{} points: projection within {:.1e} px, undistortion within {:.1e}",
        points.len(),
        worst.0,
        worst.1
    );
    assert!(worst.0 < 1e-6, "projection differs by {} px", worst.0);
    assert!(worst.1 < 1e-9, "undistortion differs by {}", worst.1);
}

#[test]
fn undistorting_a_textured_image_matches_opencv_remap() {
    let camera = camera();
    let (w, h) = (camera.width as usize, camera.height as usize);
    // A smooth texture: bilinear interpolation is then well defined to within rounding.
    let data: Vec<u8> = (0..w * h * 3)
        .map(|i| {
            let (x, y, c) = ((i / 3 % w) as f64, (i / 3 / w) as f64, i % 3);
            let value = 127.5 + 120.0 * ((x / 23.0 + c as f64).sin() * (y / 17.0 - c as f64).cos());
            value.round() as u8
        })
        .collect();
    let image = RgbImage {
        width: w as u32,
        height: h as u32,
        data,
    };
    let ours = undistort_image(&camera, &image);
    let dir = tempfile::tempdir().unwrap();
    let (input_file, output_file) = (dir.path().join("in.raw"), dir.path().join("out.raw"));
    std::fs::write(&input_file, &image.data).unwrap();
    let script = format!(
        "{OPENCV_CAMERA}
img = np.fromfile(data['input'], np.uint8).reshape({h}, {w}, 3)
mapx, mapy = cv2.initUndistortRectifyMap(K, D, None, K, ({w}, {h}), cv2.CV_32FC1)
out = cv2.remap(img, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
out.tofile(data['output'])
print(json.dumps({{'inside': int((mapx >= 0).sum())}}))
"
    );
    let input = serde_json::json!({
        "camera": camera_json(&camera),
        "input": input_file.display().to_string(),
        "output": output_file.display().to_string(),
    });
    python(&script, &input.to_string());
    let reference = std::fs::read(&output_file).unwrap();
    assert_eq!(reference.len(), ours.data.len());
    // OpenCV interpolates in fixed point (1/32 pixel steps) and black-fills differently within
    // half a pixel of the border: compare where both have image, and count the border apart.
    let (mut compared, mut total_error, mut worst, mut border_disagree) = (0usize, 0.0f64, 0u8, 0);
    for p in 0..w * h {
        let (a, b) = (&ours.data[p * 3..p * 3 + 3], &reference[p * 3..p * 3 + 3]);
        let (black_a, black_b) = (a == [0, 0, 0], b == [0, 0, 0]);
        if black_a || black_b {
            border_disagree += usize::from(black_a != black_b);
            continue;
        }
        compared += 1;
        for (x, y) in a.iter().zip(b) {
            let d = x.abs_diff(*y);
            worst = worst.max(d);
            total_error += f64::from(d);
        }
    }
    let mean = total_error / (3 * compared) as f64;
    println!(
        "{compared} pixels compared: mean |difference| {mean:.3}, worst {worst}; {border_disagree} border pixels black in one only"
    );
    assert!(compared > w * h * 3 / 4, "{compared} pixels compared");
    assert!(mean < 0.3, "mean difference {mean}");
    assert!(worst <= 3, "worst difference {worst}");
    assert!(
        border_disagree < (w + h) * 2,
        "{border_disagree} border pixels"
    );
}
