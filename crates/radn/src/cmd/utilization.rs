//! `radn eval --utilization`: how much each frame of the window contributes to a network's
//! kernels (paper Table 1 and Fig. 6).

use std::path::Path;

use anyhow::Result;
use radn_core::align::{align_window, window_indices};
use radn_core::frame::{Frame, Requirements};

use super::eval::{write_atomic, write_png, Args};
use crate::input::sequence_files;

/// Prints per-frame mean and max kernel weight over all pixels of all frames evaluated, and
/// writes heat maps of the centre frame's share.
pub fn run(a: &Args) -> Result<()> {
    let input = a.input.as_ref().expect("clap requires --input");
    let files = sequence_files(input, a.frames.as_deref())?;
    let device = radn_nn::burn::tensor::Device::flex();
    let d = crate::model::load(a.model.as_deref(), &device)?;
    let model = crate::model::label(a.model.as_deref());
    let t = d.config.frames;
    let net = radn_nn::infer::NetworkDenoiser::new(d, device);
    let reader = a.channels.reader(&files[0].1, Requirements::DENOISE)?;
    let frames: Vec<Frame> = files
        .iter()
        .map(|(_, p)| reader.read(p).map(|r| r.0))
        .collect::<Result<_, _>>()?;
    let (mut sum, mut max, mut count) = (vec![0f64; t], vec![0f32; t], 0usize);
    let pb = crate::progress::frames(frames.len() as u64, "utilisation");
    let mut rows = Vec::new();
    for (pos, (number, _)) in files.iter().enumerate() {
        let window: Vec<Option<&Frame>> = window_indices(pos, frames.len(), t / 2)
            .iter()
            .map(|i| i.map(|i| &frames[i]))
            .collect();
        let mass = net.utilization(&align_window(&window, &net.align));
        let mut frame_means = Vec::new();
        for (k, m) in mass.iter().enumerate() {
            sum[k] += m.data().iter().map(|&v| v as f64).sum::<f64>();
            max[k] = max[k].max(m.data().iter().copied().fold(0.0, f32::max));
            frame_means.push(m.data().iter().map(|&v| v as f64).sum::<f64>() / m.pixels() as f64);
        }
        count += mass[0].pixels();
        rows.push(serde_json::json!({"frame": number, "mean": frame_means}));
        if let Some(dir) = &a.heatmaps {
            heatmap(
                &mass[t / 2],
                &dir.join(format!("centre_share_{number:04}.png")),
            )?;
        }
        pb.inc(1);
    }
    pb.finish_and_clear();
    let offsets: Vec<i64> = (0..t as i64).map(|k| k - (t / 2) as i64).collect();
    println!(
        "{:>6} {}",
        "frame",
        offsets
            .iter()
            .map(|o| format!("{o:>8}"))
            .collect::<String>()
    );
    println!(
        "{:>6} {}",
        "avg",
        sum.iter()
            .map(|s| format!("{:>8.4}", s / count as f64))
            .collect::<String>()
    );
    println!(
        "{:>6} {}",
        "max",
        max.iter().map(|m| format!("{m:>8.4}")).collect::<String>()
    );
    if let Some(p) = &a.json {
        let v = serde_json::json!({
            "model": model, "input": input, "offsets": offsets,
            "avg": sum.iter().map(|s| s / count as f64).collect::<Vec<_>>(), "max": max, "frames": rows,
        });
        write_atomic(p, serde_json::to_string_pretty(&v)?.as_bytes())?;
    }
    Ok(())
}

/// Writes a weight map in [0, 1] as an 8-bit grey PNG (white = all weight on the centre frame).
fn heatmap(plane: &radn_core::Plane, path: &Path) -> Result<()> {
    let bytes: Vec<u8> = plane
        .data()
        .iter()
        .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    write_png(
        path,
        &bytes,
        plane.width(),
        plane.height(),
        png::ColorType::Grayscale,
    )
}
