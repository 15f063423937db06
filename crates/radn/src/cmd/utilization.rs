//! `radn eval --utilization`: how much each frame of the window contributes to a network's
//! kernels (paper Table 1 and Fig. 6).

use std::path::PathBuf;

use anyhow::Result;
use radn_core::denoiser::WindowDenoiser;
use radn_core::frame::Requirements;
use radn_core::output::write_bytes_atomically;
use radn_core::sequence::sequence_files;
use radn_core::window::WindowReader;
use radn_nn::infer::utilization::{write_heatmap, Utilization};
use radn_nn::infer::NetworkDenoiser;

use super::eval::Args;

/// Prints per-frame mean and max kernel weight over all pixels of all frames evaluated, and
/// writes heat maps of the centre frame's share.
pub fn run(a: &Args) -> Result<()> {
    let input = a.input.as_ref().expect("clap requires --input");
    let files = sequence_files(input, a.frames.as_deref())?;
    let device = radn_nn::burn::tensor::Device::flex();
    let net = NetworkDenoiser::new(crate::model::load(a.model.as_deref(), &device)?, device);
    let model = crate::model::label(a.model.as_deref());
    let reader = a.channels.reader(&files[0].1, Requirements::DENOISE)?;
    let paths: Vec<PathBuf> = files.iter().map(|(_, p)| p.clone()).collect();
    let mut windows = WindowReader::new(&reader, &paths, net.radius());
    let mut stats = Utilization::new(2 * net.radius() + 1);
    let pb = crate::progress::frames(files.len() as u64, "utilisation");
    for (pos, (number, _)) in files.iter().enumerate() {
        let mass = net.utilization(&windows.aligned(pos, &net.align)?);
        if let Some(dir) = &a.heatmaps {
            write_heatmap(
                &mass[net.radius()],
                &dir.join(format!("centre_share_{number:04}.png")),
            )?;
        }
        stats.add(*number, &mass);
        pb.inc(1);
    }
    pb.finish_and_clear();
    print!("{}", stats.table());
    if let Some(p) = &a.json {
        let json = stats.to_json(&model.to_string_lossy(), input);
        write_bytes_atomically(p, json.as_bytes())?;
    }
    Ok(())
}
