//! `radn prepare`: tile datasets for training.

use std::path::PathBuf;

use anyhow::Result;
use radn_core::guide::oidn_settings::{OidnQuality, OidnSettings, Prefilter};
use radn_core::setting::{Positive, Setting};
use radn_train::dataset::{prepare, PrepareOptions};

/// Arguments of `radn prepare`.
#[derive(clap::Args)]
pub struct Args {
    /// A rendered split (scenes in the datagen layout; pseudo-references in `pseudo/` from
    /// `radn pseudoref`, or in `oidn/` from datagen's teacher).
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
    /// The level folder of the pseudo-reference targets: `pseudo` (classic, `radn pseudoref`)
    /// or `oidn` (the datagen teacher render denoised by Intel Open Image Denoise), or `ref`
    /// (a split's high-spp references: windows of the frames that have one get it as target).
    #[arg(long, default_value = radn_train::dataset::DEFAULT_PSEUDO_LEVEL)]
    pub pseudo: String,
    /// Also store each input frame's guide, for training a guided network (`oidn`: Intel
    /// Open Image Denoise of that very render; `denoised` or a layer: read from the files).
    #[command(flatten)]
    pub guide: crate::input::GuideArgs,
    /// With `--guide oidn`: OIDN's beauty filter quality (high, balanced, fast). A model
    /// trained on these tiles keeps it in its recipe, so it is run on guides like these.
    #[arg(long, value_name = "QUALITY", default_value = "high")]
    pub guide_quality: OidnQuality,
    /// With `--guide oidn`: how the albedo and normal are cleaned before the beauty filter
    /// (high, balanced, fast; `off`: read noisy, one OIDN filter per frame). Kept in the
    /// trained model's recipe like `--guide-quality`.
    #[arg(long, value_name = "high|balanced|fast|off", default_value = "high")]
    pub guide_prefilter: Prefilter,
    /// With a guide: align the stored windows with the guide term of the confidence, as a
    /// guided model's recipe does (`auto`: its tolerance; `off`, the default, as every shipped
    /// model's tiles were made: the geometric terms alone).
    #[arg(long, value_name = "auto|off|TOL", default_value = "off")]
    pub guide_confidence: Setting<Positive>,
    /// How alignment samples the side frames between pixels: `bilinear` (the default model's
    /// tiles) or `catmull-rom` (keeps one-pixel detail through subpixel motion; the compiled-in
    /// guided model's). A network trains only on tiles prepared the way its description's
    /// `resampling` says.
    #[arg(long, value_enum, default_value_t = crate::input::ResamplingArg::Bilinear)]
    pub resampling: crate::input::ResamplingArg,
    /// Loosen alignment's confidence terms that compare sampled buffers (albedo, normal,
    /// depth) with each window's noise level, up to K times, as a model's recipe does at
    /// inference, so a network trains on the windows it will see (`auto`: the recipe's for
    /// this guide; `off`, the default, as every shipped model's tiles were made: strict).
    #[arg(long, value_name = "auto|off|K", default_value = "off")]
    pub loosen_confidence: Setting<Positive>,
    /// The albedo and normal the tiles hold: as rendered, or cleaned first by OIDN's
    /// standard prefilters (compiled in), for fine-tuning a converted clean-auxiliary U-Net
    /// (`radn model convert … --aux prefiltered`), which reads them so at inference.
    #[arg(long, value_enum, default_value_t = TileAux::Rendered)]
    pub aux: TileAux,
}

/// The auxiliaries `radn prepare` stores.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum TileAux {
    /// As rendered.
    Rendered,
    /// Cleaned by OIDN's `rt_alb` and `rt_nrm`, each frame whole, before alignment.
    Prefiltered,
}

/// Cuts the tiles.
pub fn run(a: Args) -> Result<()> {
    let oidn = OidnSettings {
        quality: a.guide_quality,
        prefilter: a.guide_prefilter,
    };
    if !oidn.is_default() && a.guide.guide != radn_core::guide::GuideChoice::Oidn {
        anyhow::bail!(
            "--guide-quality and --guide-prefilter say how OIDN makes the guides: they need \
             --guide oidn"
        );
    }
    let scenes = radn_core::io::sequence::scene_folders(&a.data, "high")?.len();
    let pb = crate::progress::frames(scenes as u64, "scenes");
    // `auto` takes the values a model of this kind is tuned with: its recipe
    let recipe = radn_nn::Recipe::for_kind(a.guide.guide.is_some());
    let loosen = a
        .loosen_confidence
        .resolve(recipe.confidence.loosen_sampled.map(Positive))
        .map(|k| k.0);
    if let Some(k) = loosen.filter(|k| *k < 1.0) {
        anyhow::bail!("--loosen-confidence {k}: a loosening is a factor of at least 1");
    }
    let opts = PrepareOptions {
        pseudo_level: a.pseudo.clone(),
        guide: a.guide.guide.clone(),
        oidn_threads: a.guide.oidn_threads,
        oidn,
        guide_confidence: a
            .guide_confidence
            .resolve(recipe.confidence.guide.map(Positive))
            .map(|t| t.0),
        resampling: a.resampling.into(),
        loosen_sampled_terms: loosen,
        schedule: recipe.schedule,
        aux_prefilter: match a.aux {
            TileAux::Rendered => None,
            TileAux::Prefiltered => Some(std::sync::Arc::new(crate::model::aux_prefilter()?)),
        },
        ..PrepareOptions::new(a.tile, a.tiles_per_window, a.seed)
    };
    let m = prepare(&a.data, &a.out, &opts, |done, _| {
        pb.set_position(done as u64)
    })?;
    pb.finish_and_clear();
    println!(
        "{} tiles of {}x{} from {} scenes ({} with a pseudo-reference from '{}/'{}) -> {}",
        m.records,
        m.tile,
        m.tile,
        m.scenes.len(),
        m.with_pseudo,
        m.pseudo_level,
        m.guide
            .as_ref()
            .map_or(String::new(), |g| match g.as_str() {
                "oidn" => format!(", guides: oidn, {}", m.oidn),
                _ => format!(", guides: {g}"),
            }),
        a.out.display()
    );
    Ok(())
}
