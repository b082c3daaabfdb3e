//! `relief-synth`: writes a SYNTHETIC fractal DEM (seeded fBm of value noise) of any size, for
//! scale tests and benchmarks. Real DEMs stay the main test input; every file this tool writes is
//! named and tagged as synthetic (TIFF ImageDescription / the PNG file name it suggests).
//!
//! The terrain is generated row by row and streamed into a GeoTIFF (float32, strips, projected,
//! with ModelPixelScale so `relief convert` knows the post spacing) or a 16-bit grayscale PNG
//! (decimetres above −1000 m: pass `--z-scale 0.1 --z-offset -1000` to convert). Memory: one strip.

use std::fs::File;
use std::io::{BufWriter, Seek, Write};
use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::{Parser, ValueEnum};
use rayon::prelude::*;
use tiff::encoder::{colortype, TiffEncoder, TiffKind, TiffKindBig, TiffKindStandard};
use tiff::tags::Tag;

#[derive(Clone, Copy, ValueEnum)]
enum Format {
    /// GeoTIFF float32 metres, uncompressed strips.
    Tiff,
    /// 16-bit grayscale PNG, decimetres above −1000 m.
    Png16,
    /// SYNTHETIC imagery: an 8-bit RGB PNG of `--size` pixels a side coloured from the same
    /// terrain (by height, with per-pixel grain), to drape over it (`--imagery`).
    RgbPng,
}

/// Write a synthetic fractal terrain (fBm) as a DEM.
#[derive(Parser)]
#[command(name = "relief-synth", about = "Write a SYNTHETIC fractal DEM (for scale tests; not real data)")]
struct Args {
    /// Output file (use a name that says synthetic, e.g. synthetic_4097.tif).
    out: PathBuf,
    /// Posts per side.
    #[arg(long, default_value_t = 4097)]
    size: u32,
    /// Random seed; the same seed and size give the same bytes.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Post spacing in metres (written as GeoTIFF ModelPixelScale).
    #[arg(long, default_value_t = 10.0)]
    spacing: f64,
    /// Height range in metres of the largest features.
    #[arg(long, default_value_t = 2500.0)]
    relief_m: f64,
    /// Roughness as a Hurst exponent H: each octave (half the wavelength) has 2^-H of the
    /// previous one's amplitude. 1.0 is smooth; real terrain is rougher, about 0.6 to 0.8.
    #[arg(long, default_value_t = 1.0)]
    hurst: f64,
    #[arg(long, value_enum, default_value = "tiff")]
    format: Format,
}

/// Hash of a lattice point to [0, 1).
#[inline(always)]
fn hash(seed: u64, x: i64, y: i64) -> f32 {
    let mut h = seed ^ (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    h ^= h >> 31;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 29;
    (h >> 40) as f32 / (1u64 << 24) as f32
}

/// Smoothly interpolated value noise at (x, y) in lattice units.
#[inline(always)]
fn value_noise(seed: u64, x: f32, y: f32) -> f32 {
    let (xf, yf) = (x.floor(), y.floor());
    let (xi, yi) = (xf as i64, yf as i64);
    let (tx, ty) = (x - xf, y - yf);
    let (sx, sy) = (tx * tx * (3.0 - 2.0 * tx), ty * ty * (3.0 - 2.0 * ty));
    let a = hash(seed, xi, yi);
    let b = hash(seed, xi + 1, yi);
    let c = hash(seed, xi, yi + 1);
    let d = hash(seed, xi + 1, yi + 1);
    let top = a + (b - a) * sx;
    let bottom = c + (d - c) * sx;
    top + (bottom - top) * sy
}

/// Fractal Brownian motion with `octaves` octaves; the coarsest wavelength is the whole grid.
fn height(seed: u64, size: u32, octaves: u32, relief_m: f32, persistence: f32, x: u32, y: u32) -> f32 {
    let mut f = 2.0 / size as f32;
    let mut amp = 1.0f32;
    let mut sum = 0.0f32;
    let mut norm = 0.0f32;
    for o in 0..octaves {
        sum += amp
            * value_noise(
                seed.wrapping_add((o as u64).wrapping_mul(0x632B_E59B_D9B4_E019)),
                x as f32 * f,
                y as f32 * f,
            );
        norm += amp;
        amp *= persistence;
        f *= 2.0;
    }
    // Square the normalised sum for valleys that flatten and peaks that sharpen.
    let v = sum / norm;
    relief_m * v * v
}

fn row(args: &Args, octaves: u32, y: u32, out: &mut [f32]) {
    for (x, v) in out.iter_mut().enumerate() {
        *v = height(args.seed, args.size, octaves, args.relief_m as f32, (-args.hurst).exp2() as f32, x as u32, y);
    }
}

fn write_tiff<W: Write + Seek, K: TiffKind>(mut enc: TiffEncoder<W, K>, args: &Args, octaves: u32) -> Result<()> {
    let n = args.size;
    let mut image = enc.new_image::<colortype::Gray32Float>(n, n)?;
    const ROWS: u32 = 16;
    image.rows_per_strip(ROWS)?;
    let desc = format!(
        "relief SYNTHETIC fractal terrain: fBm value noise, seed {}, {} octaves, {} m relief, Hurst {}",
        args.seed, octaves, args.relief_m, args.hurst
    );
    image.encoder().write_tag(Tag::ImageDescription, desc.as_str())?;
    image.encoder().write_tag(Tag::ModelPixelScaleTag, &[args.spacing, args.spacing, 0.0][..])?;
    image.encoder().write_tag(Tag::ModelTiepointTag, &[0.0, 0.0, 0.0, 0.0, n as f64 * args.spacing, 0.0][..])?;
    // GeoKey directory: version 1.1.0, 1 key: GTModelTypeGeoKey (1024) = 1 (projected).
    image.encoder().write_tag(Tag::GeoKeyDirectoryTag, &[1u16, 1, 0, 1, 1024, 0, 1, 1][..])?;
    let mut strip = vec![0f32; (ROWS * n) as usize];
    let bar = relief::sys::progress::Progress::new(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .bar("synth", n as u64, "rows");
    let mut y0 = 0;
    while y0 < n {
        let rows = ROWS.min(n - y0);
        let buf = &mut strip[..(rows * n) as usize];
        buf.par_chunks_mut(n as usize).enumerate().for_each(|(k, r)| row(args, octaves, y0 + k as u32, r));
        image.write_strip(buf)?;
        y0 += rows;
        bar.inc(rows as u64);
    }
    image.finish()?;
    bar.finish_and_clear();
    Ok(())
}

fn write_png(file: BufWriter<File>, args: &Args, octaves: u32) -> Result<()> {
    let n = args.size;
    let mut enc = png::Encoder::new(file, n, n);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Sixteen);
    enc.set_compression(png::Compression::Fast);
    enc.add_text_chunk(
        "Description".into(),
        format!("relief SYNTHETIC fractal terrain, seed {}; decimetres above -1000 m", args.seed),
    )?;
    let mut writer = enc.write_header()?;
    let mut stream = writer.stream_writer()?;
    let mut heights = vec![0f32; n as usize];
    let mut bytes = vec![0u8; 2 * n as usize];
    for y in 0..n {
        row(args, octaves, y, &mut heights);
        for (b, h) in bytes.chunks_exact_mut(2).zip(&heights) {
            let q = ((h + 1000.0) * 10.0).round().clamp(0.0, 65535.0) as u16;
            b.copy_from_slice(&q.to_be_bytes());
        }
        stream.write_all(&bytes)?;
    }
    stream.finish()?;
    Ok(())
}

fn main() -> Result<()> {
    let args = Args::parse();
    if args.size < 2 || args.spacing.is_nan() || args.spacing <= 0.0 {
        bail!("--size must be at least 2 and --spacing positive");
    }
    if !(args.hurst > 0.0 && args.hurst <= 2.0) {
        bail!("--hurst must be in (0, 2], got {}", args.hurst);
    }
    let octaves = 32 - args.size.leading_zeros(); // down to about one post per wavelength
    let file = File::create(&args.out).with_context(|| format!("{}: cannot create", args.out.display()))?;
    let w = BufWriter::with_capacity(1 << 20, file);
    match args.format {
        Format::Tiff => {
            let bytes = args.size as u64 * args.size as u64 * 4;
            if bytes > 3_500_000_000 {
                write_tiff::<_, TiffKindBig>(TiffEncoder::new_big(w)?, &args, octaves)?
            } else {
                write_tiff::<_, TiffKindStandard>(TiffEncoder::new(w)?, &args, octaves)?
            }
        }
        Format::Png16 => write_png(w, &args, octaves)?,
        Format::RgbPng => write_rgb_png(w, &args, octaves)?,
    }
    let what = if matches!(args.format, Format::RgbPng) { "imagery" } else { "terrain" };
    eprintln!("wrote SYNTHETIC {0}x{0} {what} to {1}", args.size, args.out.display());
    Ok(())
}

/// Colour of a height (0..relief): lowland green, then brown, then rock grey and snow.
fn colour(t: f32) -> [f32; 3] {
    const STOPS: [(f32, [f32; 3]); 5] = [
        (0.0, [46.0, 94.0, 42.0]),
        (0.25, [112.0, 138.0, 64.0]),
        (0.5, [140.0, 110.0, 72.0]),
        (0.75, [128.0, 124.0, 120.0]),
        (1.0, [240.0, 240.0, 245.0]),
    ];
    let t = t.clamp(0.0, 1.0);
    let i = STOPS.iter().rposition(|s| s.0 <= t).unwrap_or(0).min(STOPS.len() - 2);
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    let f = (t - a.0) / (b.0 - a.0);
    [0, 1, 2].map(|c| a.1[c] + (b.1[c] - a.1[c]) * f)
}

fn write_rgb_png(file: BufWriter<File>, args: &Args, octaves: u32) -> Result<()> {
    let n = args.size;
    let mut enc = png::Encoder::new(file, n, n);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    enc.add_text_chunk(
        "Description".into(),
        format!("relief SYNTHETIC imagery of the fractal terrain of seed {}; not a photograph", args.seed),
    )?;
    let mut writer = enc.write_header()?;
    let mut stream = writer.stream_writer()?;
    const ROWS: u32 = 64;
    let mut heights = vec![0f32; (ROWS * n) as usize];
    let mut bytes = vec![0u8; (3 * ROWS * n) as usize];
    let bar = relief::sys::progress::Progress::new(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .bar("synth", n as u64, "rows");
    let mut y0 = 0;
    while y0 < n {
        let rows = ROWS.min(n - y0);
        let hs = &mut heights[..(rows * n) as usize];
        hs.par_chunks_mut(n as usize).enumerate().for_each(|(k, r)| row(args, octaves, y0 + k as u32, r));
        for (i, (b, h)) in bytes.chunks_exact_mut(3).zip(hs.iter()).enumerate() {
            let (x, y) = (i as i64 % n as i64, y0 as i64 + i as i64 / n as i64);
            let grain = (hash(args.seed ^ 0x5eed, x, y) - 0.5) * 24.0;
            let c = colour(h / args.relief_m as f32);
            for k in 0..3 {
                b[k] = (c[k] + grain).round().clamp(0.0, 255.0) as u8;
            }
        }
        stream.write_all(&bytes[..(3 * rows * n) as usize])?;
        y0 += rows;
        bar.inc(rows as u64);
    }
    stream.finish()?;
    bar.finish_and_clear();
    Ok(())
}
