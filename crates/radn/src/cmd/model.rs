//! `radn model`: a model file's network and recipe, and a copy of it with its recipe tuned, so a
//! setting chosen by measurement ships inside the model rather than as a flag every run repeats.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use radn_nn::device::ComputeDevice;

use crate::input::{check_threshold, tune_pairs};

/// Arguments of `radn model`.
#[derive(clap::Args)]
pub struct Args {
    /// The model file (SafeTensors, as `radn train` writes).
    pub file: PathBuf,
    /// Change a recipe setting in the copy written to --out (`radn denoise --tune help` lists
    /// the keys).
    #[arg(long, value_name = "KEY=VALUE", requires = "out")]
    pub tune: Vec<String>,
    /// Where the tuned copy goes (a new file: neither the model nor any other file is replaced).
    #[arg(short, long, value_name = "FILE")]
    pub out: Option<PathBuf>,
}

/// Prints the network and recipe, or writes the copy with its recipe tuned.
pub fn run(a: Args) -> Result<()> {
    let device = ComputeDevice::Cpu.open()?;
    let mut model = radn_nn::model::store::load(&a.file, &device)?;
    let Some(out) = a.out else {
        println!(
            "# {}\n\n# network\n{}",
            a.file.display(),
            model.config.to_toml()
        );
        println!("# recipe\n{}", model.recipe.to_toml());
        return Ok(());
    };
    if out.exists() {
        bail!("'{}' exists; radn model writes a new file", out.display());
    }
    for (key, value) in tune_pairs(&a.tune)? {
        model.recipe.set(key, value).map_err(anyhow::Error::msg)?;
    }
    if let Some(t) = model.recipe.threshold {
        check_threshold(t, &model.config)?;
    }
    radn_nn::model::store::save(&model, &out)
        .with_context(|| format!("writing the tuned model to '{}'", out.display()))?;
    println!("{}: recipe\n{}", out.display(), model.recipe.to_toml());
    Ok(())
}
