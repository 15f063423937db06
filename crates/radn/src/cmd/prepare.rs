//! `radn prepare`: tile datasets for training.

use std::path::PathBuf;

use anyhow::Result;
use radn_nn::train::dataset::{prepare, PrepareOptions};

/// Arguments of `radn prepare`.
#[derive(clap::Args)]
pub struct Args {
    /// A rendered split (scenes in the datagen layout, with `pseudo/` levels from `radn pseudoref`).
    #[arg(long)]
    pub data: PathBuf,
    /// Output folder for the shards and manifest.
    #[arg(long)]
    pub out: PathBuf,
    /// Tile size in pixels.
    #[arg(long, default_value_t = 128)]
    pub tile: usize,
    /// Tiles cut from every window.
    #[arg(long, default_value_t = 4)]
    pub tiles_per_window: usize,
    /// Seed of the tile positions (the same seed gives the same dataset).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// Cuts the tiles.
pub fn run(a: Args) -> Result<()> {
    let scenes = radn_core::sequence::scene_folders(&a.data, "high")?.len();
    let pb = crate::progress::frames(scenes as u64, "scenes");
    let opts = PrepareOptions {
        tile: a.tile,
        tiles_per_window: a.tiles_per_window,
        seed: a.seed,
        frames: 5,
    };
    let m = prepare(&a.data, &a.out, &opts, |done, _| {
        pb.set_position(done as u64)
    })?;
    pb.finish_and_clear();
    println!(
        "{} tiles of {}x{} from {} scenes ({} with a pseudo-reference) -> {}",
        m.records,
        m.tile,
        m.tile,
        m.scenes.len(),
        m.with_pseudo,
        a.out.display()
    );
    Ok(())
}
