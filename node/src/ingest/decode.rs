//! Decode colour (raw and compressed) and depth images into [`RgbImage`] and [`DepthImage`].
//! Depth decoding turns every invalid pixel (0 in 16UC1, NaN, ∞ or ≤ 0 in 32FC1) into NaN.

use groupforward_msgs::sensor_msgs::{CompressedImage, Image};

use super::reject::{reject, Reject, Rejection};
use crate::frame::{DepthImage, RgbImage};

pub(super) fn check_dimensions(width: u32, height: u32, max_side: u32) -> Result<(), Rejection> {
    if width == 0 || height == 0 || width > max_side || height > max_side {
        return reject(
            Reject::BadDimensions,
            format!("{width}x{height} (allowed 1..={max_side} per side)"),
        );
    }
    Ok(())
}

/// Bytes per pixel and channel order of the colour encodings we accept.
fn colour_layout(encoding: &str) -> Option<(usize, [usize; 3])> {
    match encoding {
        "rgb8" => Some((3, [0, 1, 2])),
        "bgr8" => Some((3, [2, 1, 0])),
        "rgba8" => Some((4, [0, 1, 2])),
        "bgra8" => Some((4, [2, 1, 0])),
        "mono8" | "8UC1" => Some((1, [0, 0, 0])),
        _ => None,
    }
}

/// Rows of `step` bytes each holding at least `row_bytes` of pixel data.
fn check_layout(msg: &Image, bytes_per_pixel: usize) -> Result<(), Rejection> {
    let row_bytes = msg.width as usize * bytes_per_pixel;
    if (msg.step as usize) < row_bytes {
        return reject(
            Reject::SizeMismatch,
            format!(
                "step {} < width {} x {bytes_per_pixel}",
                msg.step, msg.width
            ),
        );
    }
    let expected = msg.step as usize * msg.height as usize;
    if msg.data.len() != expected {
        return reject(
            Reject::SizeMismatch,
            format!(
                "{} data bytes, step x height = {expected} ({}x{} {})",
                msg.data.len(),
                msg.width,
                msg.height,
                msg.encoding
            ),
        );
    }
    Ok(())
}

/// Decode a raw colour image (rgb8, bgr8, rgba8, bgra8, mono8) to RGB.
pub fn decode_image(msg: &Image, max_side: u32) -> Result<RgbImage, Rejection> {
    check_dimensions(msg.width, msg.height, max_side)?;
    let Some((bpp, order)) = colour_layout(&msg.encoding) else {
        return reject(
            Reject::UnknownEncoding,
            format!("colour encoding `{}`", msg.encoding),
        );
    };
    check_layout(msg, bpp)?;
    let (w, h) = (msg.width as usize, msg.height as usize);
    let mut data = Vec::with_capacity(w * h * 3);
    for row in msg.data.chunks_exact(msg.step as usize).take(h) {
        for px in row[..w * bpp].chunks_exact(bpp) {
            data.extend_from_slice(&[px[order[0]], px[order[1]], px[order[2]]]);
        }
    }
    Ok(RgbImage {
        width: msg.width,
        height: msg.height,
        data,
    })
}

/// Decode a jpeg / png `CompressedImage` to RGB.
pub fn decode_compressed(msg: &CompressedImage, max_side: u32) -> Result<RgbImage, Rejection> {
    let format = msg.format.to_ascii_lowercase();
    if format.contains("compresseddepth") {
        return reject(
            Reject::UnknownEncoding,
            format!("compressed depth `{}` on a colour topic", msg.format),
        );
    }
    let reader = image::ImageReader::new(std::io::Cursor::new(&msg.data))
        .with_guessed_format()
        .map_err(|e| Rejection {
            reason: Reject::CompressedDecodeFailed,
            detail: e.to_string(),
        })?;
    let Some(kind) = reader.format() else {
        return reject(
            Reject::CompressedDecodeFailed,
            format!("format `{}`: not jpeg or png data", msg.format),
        );
    };
    if !matches!(kind, image::ImageFormat::Jpeg | image::ImageFormat::Png) {
        return reject(
            Reject::UnknownEncoding,
            format!("compressed format {kind:?}"),
        );
    }
    // Check the header's size before decoding pixels, so a hostile header cannot allocate much.
    let (width, height) = reader.into_dimensions().map_err(|e| Rejection {
        reason: Reject::CompressedDecodeFailed,
        detail: e.to_string(),
    })?;
    check_dimensions(width, height, max_side)?;
    let decoded = image::load_from_memory_with_format(&msg.data, kind).map_err(|e| Rejection {
        reason: Reject::CompressedDecodeFailed,
        detail: e.to_string(),
    })?;
    let rgb = decoded.to_rgb8();
    Ok(RgbImage {
        width: rgb.width(),
        height: rgb.height(),
        data: rgb.into_raw(),
    })
}

/// Decode a depth image: 16UC1 / mono16 in millimetres (0 = invalid) or 32FC1 in metres.
pub fn decode_depth(msg: &Image, max_side: u32) -> Result<DepthImage, Rejection> {
    check_dimensions(msg.width, msg.height, max_side)?;
    let bpp = match msg.encoding.as_str() {
        "16UC1" | "mono16" => 2,
        "32FC1" => 4,
        other => {
            return reject(
                Reject::UnknownEncoding,
                format!("depth encoding `{other}` (expected 16UC1 or 32FC1)"),
            )
        }
    };
    check_layout(msg, bpp)?;
    let (w, h) = (msg.width as usize, msg.height as usize);
    let big = msg.is_bigendian != 0;
    let mut metres = Vec::with_capacity(w * h);
    for row in msg.data.chunks_exact(msg.step as usize).take(h) {
        for px in row[..w * bpp].chunks_exact(bpp) {
            let value = if bpp == 2 {
                let raw = [px[0], px[1]];
                let mm = if big {
                    u16::from_be_bytes(raw)
                } else {
                    u16::from_le_bytes(raw)
                };
                if mm == 0 {
                    f32::NAN
                } else {
                    f32::from(mm) * 1e-3
                }
            } else {
                let raw = [px[0], px[1], px[2], px[3]];
                let m = if big {
                    f32::from_be_bytes(raw)
                } else {
                    f32::from_le_bytes(raw)
                };
                if m.is_finite() && m > 0.0 {
                    m
                } else {
                    f32::NAN
                }
            };
            metres.push(value);
        }
    }
    Ok(DepthImage {
        width: msg.width,
        height: msg.height,
        metres,
    })
}

#[cfg(test)]
mod tests {
    use super::super::test_messages::{header, image};
    use super::*;

    #[test]
    fn colour_encodings_convert_to_rgb() {
        let mut bgr = image(2, 1, "bgr8", 3, 0);
        bgr.data = vec![1, 2, 3, 4, 5, 6];
        assert_eq!(decode_image(&bgr, 64).unwrap().data, vec![3, 2, 1, 6, 5, 4]);
        let mut rgba = image(1, 1, "rgba8", 4, 0);
        rgba.data = vec![9, 8, 7, 255];
        assert_eq!(decode_image(&rgba, 64).unwrap().data, vec![9, 8, 7]);
        let mut mono = image(1, 1, "mono8", 1, 0);
        mono.data = vec![42];
        assert_eq!(decode_image(&mono, 64).unwrap().data, vec![42, 42, 42]);
        // Row padding (step > width * bpp) is skipped.
        let mut padded = image(1, 2, "mono8", 1, 0);
        padded.step = 4;
        padded.data = vec![1, 0, 0, 0, 2, 0, 0, 0];
        assert_eq!(
            decode_image(&padded, 64).unwrap().data,
            vec![1, 1, 1, 2, 2, 2]
        );
    }

    #[test]
    fn bad_images_are_rejected_with_reasons() {
        let reason = |m: &Image| decode_image(m, 64).unwrap_err().reason;
        let mut short = image(4, 4, "rgb8", 3, 0);
        short.data.pop();
        assert_eq!(reason(&short), Reject::SizeMismatch);
        assert_eq!(
            reason(&image(4, 4, "yuv422", 2, 0)),
            Reject::UnknownEncoding
        );
        assert_eq!(reason(&image(0, 0, "rgb8", 3, 0)), Reject::BadDimensions);
        let mut absurd = image(1, 1, "rgb8", 3, 0);
        absurd.width = 100_000;
        assert_eq!(reason(&absurd), Reject::BadDimensions);
        let mut step = image(4, 1, "rgb8", 3, 0);
        step.step = 2;
        assert_eq!(reason(&step), Reject::SizeMismatch);
    }

    #[test]
    fn depth_decodes_units_and_invalid_pixels() {
        let mut d16 = image(2, 1, "16UC1", 2, 0);
        d16.data = [1500u16, 0].iter().flat_map(|v| v.to_le_bytes()).collect();
        let d = decode_depth(&d16, 64).unwrap();
        assert!((d.metres[0] - 1.5).abs() < 1e-6 && d.metres[1].is_nan());
        let mut d32 = image(3, 1, "32FC1", 4, 0);
        d32.data = [2.25f32, f32::INFINITY, -1.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let d = decode_depth(&d32, 64).unwrap();
        assert_eq!(d.metres[0], 2.25);
        assert!(d.metres[1].is_nan() && d.metres[2].is_nan());
        assert_eq!(
            decode_depth(&image(2, 1, "rgb8", 3, 0), 64)
                .unwrap_err()
                .reason,
            Reject::UnknownEncoding
        );
    }

    #[test]
    fn compressed_png_and_jpeg_decode_and_garbage_is_rejected() {
        let rgb =
            image::RgbImage::from_fn(8, 4, |x, y| image::Rgb([x as u8 * 30, y as u8 * 60, 7]));
        for format in [image::ImageFormat::Png, image::ImageFormat::Jpeg] {
            let mut bytes = Vec::new();
            rgb.write_to(&mut std::io::Cursor::new(&mut bytes), format)
                .unwrap();
            let msg = CompressedImage {
                header: header(0, "c"),
                format: "rgb8; jpeg compressed bgr8".into(),
                data: bytes,
            };
            let out = decode_compressed(&msg, 64).unwrap();
            assert_eq!((out.width, out.height), (8, 4));
            if format == image::ImageFormat::Png {
                assert_eq!(out.data, rgb.as_raw().clone());
            }
            let mut truncated = msg.clone();
            truncated.data.truncate(20);
            assert_eq!(
                decode_compressed(&truncated, 64).unwrap_err().reason,
                Reject::CompressedDecodeFailed
            );
            // Larger than allowed: refused from the header alone.
            assert_eq!(
                decode_compressed(&msg, 4).unwrap_err().reason,
                Reject::BadDimensions
            );
        }
        let garbage = CompressedImage {
            data: vec![1, 2, 3, 4, 5],
            ..Default::default()
        };
        assert_eq!(
            decode_compressed(&garbage, 64).unwrap_err().reason,
            Reject::CompressedDecodeFailed
        );
    }

    proptest::proptest! {
        #[test]
        fn any_image_header_never_panics(w in 0u32..64, h in 0u32..64, step in 0u32..256, len in 0usize..512,
                                         enc in 0usize..8, big in 0u8..2) {
            let encodings = ["rgb8", "bgr8", "rgba8", "bgra8", "mono8", "16UC1", "32FC1", "x"];
            let msg = Image { height: h, width: w, step, encoding: encodings[enc].into(), is_bigendian: big,
                              data: vec![7; len], ..Default::default() };
            // Either a whole image or one of the named reasons, never a panic or a short buffer.
            let expected = [Reject::BadDimensions, Reject::SizeMismatch, Reject::UnknownEncoding];
            match decode_image(&msg, 32) {
                Ok(image) => proptest::prop_assert_eq!(image.data.len(), (w * h * 3) as usize),
                Err(e) => proptest::prop_assert!(expected.contains(&e.reason), "{:?}", e),
            }
            match decode_depth(&msg, 32) {
                Ok(depth) => proptest::prop_assert_eq!(depth.metres.len(), (w * h) as usize),
                Err(e) => proptest::prop_assert!(expected.contains(&e.reason), "{:?}", e),
            }
        }
    }
}
