//! `radn inspect`: what is in an EXR file.

use std::path::PathBuf;

use anyhow::Result;
use radn_core::io::exr_file::ExrFile;
use radn_core::io::mapping::ChannelMapping;

/// Arguments of `radn inspect`.
#[derive(clap::Args)]
pub struct Args {
    /// The EXR file.
    pub file: PathBuf,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// Prints parts, channels and statistics.
pub fn run(a: Args) -> Result<()> {
    let file = ExrFile::read(&a.file)?;
    let names = file.channel_names();
    let stats = file.channel_stats();
    let preset = ChannelMapping::detect(&names)
        .map(|m| m.name)
        .unwrap_or_else(|| "none".into());
    if a.json {
        let parts: Vec<serde_json::Value> = file
            .parts()
            .iter()
            .map(|p| {
                serde_json::json!({"name": p.name, "width": p.width, "height": p.height,
                    "compression": p.compression, "tiles": p.tiles, "channels": p.channels})
            })
            .collect();
        let out = serde_json::json!({
            "file": a.file, "width": file.width(), "height": file.height(), "preset": preset,
            "parts": parts, "attributes": file.custom_attribute_names(), "channels": stats,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    println!("{}", a.file.display());
    println!(
        "  size {}x{}, {} channels, preset detected: {preset}",
        file.width(),
        file.height(),
        names.len()
    );
    for p in file.parts() {
        let blocks = match p.tiles {
            Some((w, h)) => format!("tiles {w}x{h}"),
            None => "scanlines".into(),
        };
        println!(
            "  part {}: {}x{}, {} channels, {}, {}",
            p.name.as_deref().unwrap_or("(unnamed)"),
            p.width,
            p.height,
            p.channels,
            p.compression,
            blocks
        );
    }
    let attrs = file.custom_attribute_names();
    if !attrs.is_empty() {
        println!("  attributes: {}", attrs.join(", "));
    }
    let wname = stats.iter().map(|s| s.name.len()).max().unwrap_or(7).max(7);
    println!(
        "  {:wname$}  {:5}  {:>12} {:>12} {:>12} {:>7} {:>7}",
        "channel", "type", "min", "max", "mean", "NaN", "Inf"
    );
    for s in &stats {
        println!(
            "  {:wname$}  {:5}  {:>12.5} {:>12.5} {:>12.5} {:>7} {:>7}",
            s.name, s.kind, s.min, s.max, s.mean, s.nan, s.inf
        );
    }
    Ok(())
}
