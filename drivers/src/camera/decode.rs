//! Image files → 8-bit grey [`Image`], pure Rust: PGM ([`super::pgm`]) and, through the `image`
//! crate, PNG, JPEG, BMP and TIFF (8 or 16 bit, grey or colour, with or without alpha).
//!
//! The format is taken from the file's content (its magic bytes), not its extension. Colour is
//! reduced to grey with OpenCV's weights (BT.601: 0.299 R + 0.587 G + 0.114 B), so corners match
//! what `cv::imread(..., IMREAD_GRAYSCALE)` gives. 16-bit samples are scaled to 8 bits over the
//! full 0..=65535 range, except when no sample exceeds 4095 (12-bit sensor data stored in
//! 16 bits), which is scaled over 0..=4095. Every failure says why in words a user can act on:
//! missing, a directory, empty, not an image, truncated / corrupt, too large.

use std::path::Path;

use super::{pgm, Error};
use crate::traits::Image;

/// Largest image accepted (pixels), as for PGM.
pub const MAX_PIXELS: u64 = pgm::MAX_PIXELS;

/// The formats this reader decodes, for messages.
pub const FORMATS: &str = "PNG, JPEG, BMP, TIFF or PGM";

fn format_err(path: &Path, detail: impl Into<String>) -> Error {
    Error::Format {
        path: path.display().to_string(),
        detail: detail.into(),
    }
}

/// Read and decode the image file `path` (timestamp 0).
pub fn read_file(path: &Path) -> Result<Image, Error> {
    let meta = std::fs::metadata(path).map_err(|source| Error::Io {
        path: path.display().to_string(),
        source,
    })?;
    if meta.is_dir() {
        return Err(format_err(path, "is a directory, not an image file"));
    }
    let bytes = std::fs::read(path).map_err(|source| Error::Io {
        path: path.display().to_string(),
        source,
    })?;
    decode(&bytes).map_err(|detail| format_err(path, detail))
}

/// Decode an image held in memory (see the module docs); the error says what is wrong.
pub fn decode(bytes: &[u8]) -> Result<Image, String> {
    if bytes.is_empty() {
        return Err("empty file (0 bytes), not an image".into());
    }
    if matches!(bytes.get(..2), Some(b"P5") | Some(b"P2")) {
        let (width, height, data) = pgm::decode(bytes).map_err(|e| e.to_string())?;
        return Ok(Image {
            width,
            height,
            data,
            t: 0.0,
        });
    }
    let reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| format!("cannot read: {e}"))?;
    let Some(format) = reader.format() else {
        let head: String = bytes
            .iter()
            .take(8)
            .map(|b| format!("{b:02x}"))
            .collect::<Vec<_>>()
            .join(" ");
        return Err(format!(
            "not an image: the content is not {FORMATS} (first bytes {head})"
        ));
    };
    let name = format!("{format:?}").to_uppercase();
    if !matches!(
        format,
        image::ImageFormat::Png
            | image::ImageFormat::Jpeg
            | image::ImageFormat::Bmp
            | image::ImageFormat::Tiff
    ) {
        return Err(format!("{name} images are not read (convert to {FORMATS})"));
    }
    let mut reader = reader;
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(MAX_PIXELS * 16);
    reader.limits(limits);
    let img = reader.decode().map_err(|e| describe(&name, e))?;
    let (width, height) = (img.width(), img.height());
    if width == 0 || height == 0 || u64::from(width) * u64::from(height) > MAX_PIXELS {
        return Err(format!(
            "{name} of {width}×{height} pixels is out of range (at most {MAX_PIXELS} pixels)"
        ));
    }
    Ok(Image {
        width,
        height,
        data: to_grey8(img),
        t: 0.0,
    })
}

fn describe(name: &str, e: image::ImageError) -> String {
    use image::ImageError as E;
    match e {
        E::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            format!("{name} is truncated (the file ends before the image data does)")
        }
        E::Limits(l) => format!("{name} is too large to decode: {l}"),
        E::Unsupported(u) => format!("{name} variant not supported: {u}"),
        other => {
            let m = other.to_string();
            let low = m.to_lowercase();
            if low.contains("eof") || low.contains("end of") || low.contains("unexpected end") {
                format!("{name} is truncated or corrupt: {m}")
            } else {
                format!("{name} is corrupt: {m}")
            }
        }
    }
}

/// BT.601 luma of 8-bit RGB.
fn luma8(r: u8, g: u8, b: u8) -> u8 {
    ((299 * u32::from(r) + 587 * u32::from(g) + 114 * u32::from(b) + 500) / 1000) as u8
}

/// 16-bit grey samples → 8 bits (full range, or 12-bit range when nothing exceeds 4095).
fn scale16(v: Vec<u16>) -> Vec<u8> {
    let max = v.iter().copied().max().unwrap_or(0);
    let full: u32 = if max <= 4095 { 4095 } else { 65535 };
    v.into_iter()
        .map(|s| ((u32::from(s) * 255 + full / 2) / full).min(255) as u8)
        .collect()
}

fn to_grey8(img: image::DynamicImage) -> Vec<u8> {
    use image::DynamicImage as D;
    match img {
        D::ImageLuma8(g) => g.into_raw(),
        D::ImageLumaA8(g) => g.pixels().map(|p| p.0[0]).collect(),
        D::ImageRgb8(c) => c.pixels().map(|p| luma8(p.0[0], p.0[1], p.0[2])).collect(),
        D::ImageRgba8(c) => c.pixels().map(|p| luma8(p.0[0], p.0[1], p.0[2])).collect(),
        D::ImageLuma16(g) => scale16(g.into_raw()),
        D::ImageLumaA16(g) => scale16(g.pixels().map(|p| p.0[0]).collect()),
        D::ImageRgb16(c) => scale16(c.pixels().map(|p| luma16(p.0[0], p.0[1], p.0[2])).collect()),
        D::ImageRgba16(c) => scale16(c.pixels().map(|p| luma16(p.0[0], p.0[1], p.0[2])).collect()),
        other => {
            let c = other.to_rgb8();
            c.pixels().map(|p| luma8(p.0[0], p.0[1], p.0[2])).collect()
        }
    }
}

/// BT.601 luma of 16-bit RGB.
fn luma16(r: u16, g: u16, b: u16) -> u16 {
    ((299 * u64::from(r) + 587 * u64::from(g) + 114 * u64::from(b) + 500) / 1000) as u16
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{ImageBuffer, ImageFormat, Luma, Rgb};

    /// A 12×9 test pattern (left half dark, right half bright, a gradient down the rows).
    fn pattern(x: u32, y: u32) -> u8 {
        (if x < 6 { 20 } else { 200 }) + (y as u8) * 4
    }

    fn encode(img: image::DynamicImage, f: ImageFormat) -> Vec<u8> {
        let mut out = std::io::Cursor::new(Vec::new());
        img.write_to(&mut out, f).unwrap();
        out.into_inner()
    }

    fn grey8() -> image::DynamicImage {
        image::DynamicImage::ImageLuma8(ImageBuffer::from_fn(12, 9, |x, y| Luma([pattern(x, y)])))
    }

    #[test]
    fn png_bmp_tiff_grey_and_colour_8_and_16_bit_decode_to_the_same_grey() {
        let want: Vec<u8> = (0..9)
            .flat_map(|y| (0..12).map(move |x| pattern(x, y)))
            .collect();
        let rgb = image::DynamicImage::ImageRgb8(ImageBuffer::from_fn(12, 9, |x, y| {
            let v = pattern(x, y);
            Rgb([v, v, v])
        }));
        let g16 = image::DynamicImage::ImageLuma16(ImageBuffer::from_fn(12, 9, |x, y| {
            Luma([u16::from(pattern(x, y)) * 257])
        }));
        let rgb16 = image::DynamicImage::ImageRgb16(ImageBuffer::from_fn(12, 9, |x, y| {
            let v = u16::from(pattern(x, y)) * 257;
            Rgb([v, v, v])
        }));
        for (what, img, f) in [
            ("png grey8", grey8(), ImageFormat::Png),
            ("png rgb8", rgb.clone(), ImageFormat::Png),
            ("png grey16", g16.clone(), ImageFormat::Png),
            ("png rgb16", rgb16.clone(), ImageFormat::Png),
            ("bmp rgb8", rgb.clone(), ImageFormat::Bmp),
            ("tiff grey8", grey8(), ImageFormat::Tiff),
            ("tiff grey16", g16, ImageFormat::Tiff),
            ("tiff rgb16", rgb16, ImageFormat::Tiff),
        ] {
            let im = decode(&encode(img, f)).unwrap_or_else(|e| panic!("{what}: {e}"));
            assert_eq!((im.width, im.height), (12, 9), "{what}");
            assert_eq!(im.data, want, "{what}");
        }
        // JPEG is lossy: within a few grey levels.
        let im = decode(&encode(grey8(), ImageFormat::Jpeg)).unwrap();
        assert_eq!((im.width, im.height), (12, 9));
        let worst = im
            .data
            .iter()
            .zip(&want)
            .map(|(a, b)| (i16::from(*a) - i16::from(*b)).abs())
            .max()
            .unwrap();
        assert!(worst <= 24, "jpeg worst grey error {worst}");
    }

    #[test]
    fn colour_uses_opencv_weights_and_12_bit_data_is_stretched() {
        let red = image::DynamicImage::ImageRgb8(ImageBuffer::from_pixel(2, 2, Rgb([255, 0, 0])));
        assert_eq!(
            decode(&encode(red, ImageFormat::Png)).unwrap().data,
            [76; 4]
        );
        let g12 = image::DynamicImage::ImageLuma16(ImageBuffer::from_fn(2, 1, |x, _| {
            Luma([if x == 0 { 0 } else { 4095 }])
        }));
        assert_eq!(
            decode(&encode(g12, ImageFormat::Png)).unwrap().data,
            [0, 255]
        );
    }

    #[test]
    fn every_unusable_file_says_why() {
        let png = encode(grey8(), ImageFormat::Png);
        let jpg = encode(grey8(), ImageFormat::Jpeg);
        let cases: Vec<(&str, Vec<u8>, &str)> = vec![
            ("empty", vec![], "empty file"),
            ("text", b"id,x,y\n1,2,3\n".to_vec(), "not an image"),
            ("png cut", png[..png.len() / 2].to_vec(), "PNG is"),
            ("jpeg cut", jpg[..40].to_vec(), "JPEG is"),
            (
                "gif",
                b"GIF89a\x01\x00\x01\x00".to_vec(),
                "GIF images are not read",
            ),
            ("pgm cut", b"P5\n4 4\n255\nab".to_vec(), "PGM"),
        ];
        for (what, bytes, want) in cases {
            let e = decode(&bytes).expect_err(what);
            assert!(e.contains(want), "{what}: {e}");
        }
        let dir = std::env::temp_dir().join(format!("robocal-decode-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("sub.png")).unwrap();
        let e = read_file(&dir.join("sub.png")).unwrap_err().to_string();
        assert!(e.contains("sub.png") && e.contains("directory"), "{e}");
        let e = read_file(&dir.join("missing.png")).unwrap_err().to_string();
        assert!(
            e.contains("missing.png") && e.contains("No such file"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
