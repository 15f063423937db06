//! The tile scheduler: a window's rows cut into tiles with the receptive field's halo, grouped
//! into network calls of equal-sized tiles, and their results put back together.

use burn::tensor::{Tensor, TensorData};
use std::ops::Range;

use radn_core::align::AlignedWindow;
use radn_core::io::frame::Frame;
use radn_core::Plane;

use crate::infer::input::{network_input, FeatureScales, Region};
use crate::infer::stems::WindowStems;
use crate::model::GuideWeights;
use crate::profile::{timed, Stage};

use super::NetworkDenoiser;

impl NetworkDenoiser {
    /// Per-pixel kernel weight of each window frame (temporal utilisation, paper Table 1 and
    /// Fig. 6): `frames` planes summing to 1 at every pixel. A network with a frame-local stem
    /// runs it on the aligned frames here, as in training; [`NetworkDenoiser::window_utilization`]
    /// measures what `denoise` computes.
    pub fn utilization(&self, win: &AlignedWindow) -> Vec<Plane> {
        self.utilization_with(win, None, FeatureScales::of(win))
    }

    /// [`NetworkDenoiser::utilization`] of the window of frames `window` (`None` beyond the
    /// sequence ends), aligned here, with the stem features warped as
    /// [`radn_core::run::denoiser::WindowDenoiser::denoise`] warps them.
    pub fn window_utilization(&self, window: &[Option<&Frame>]) -> Vec<Plane> {
        let (win, scales) = self.align_for_centre(window);
        let stems = self
            .reuses_frame_layers()
            .then(|| WindowStems::new(window, &win, self.resampling(), |f| self.frame_stem(f)));
        self.utilization_with(&win, stems.as_ref(), scales)
    }

    fn utilization_with(
        &self,
        win: &AlignedWindow,
        stems: Option<&WindowStems>,
        scales: FeatureScales,
    ) -> Vec<Plane> {
        let t = win.frames.len();
        let zeros = |r: Region| vec![0.0f32; t * r.pixels()];
        let h = win.centre().color.height();
        let mass = self.run_tiled(win, stems, scales, 0..h, zeros, 1, |p, _, _, _| {
            p.frame_mass(t)
        });
        (0..t).map(|k| mass.select_channels(k, 1)).collect()
    }

    /// Runs the network tile by tile over rows `rows` (each tile with a halo of the receptive
    /// field, clamped to the window, so the result does not depend on the tiling) and assembles
    /// the planes of `f(prediction, guide weights, values, features)`, `values` being `[B, T, chans, h, w]`
    /// from `values(region)` and `features` the network input of the regions. Consecutive tiles
    /// whose regions have the same size share one network call, up to `batch` of them. Features
    /// and values exist for one call's tiles at a time, never for the whole frame.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn run_tiled(
        &self,
        win: &AlignedWindow,
        stems: Option<&WindowStems>,
        scales: FeatureScales,
        rows: Range<usize>,
        values: impl Fn(Region) -> Vec<f32>,
        chans: usize,
        f: impl Fn(&crate::model::Prediction, GuideWeights, Tensor<5>, &Tensor<5>) -> Tensor<4>,
    ) -> Plane {
        let w = win.centre().color.width();
        let tiles = self.tiles(win, rows.clone(), stems.is_some());
        let mut out: Option<Plane> = None;
        for call in batches(&tiles, self.batch) {
            let group = &tiles[call];
            self.run_group(
                win, stems, scales, group, &values, chans, &f, &mut out, w, &rows,
            );
        }
        out.expect("at least one tile")
    }

    /// The tiles covering rows `rows` of the window, row of tiles by row of tiles, each with its
    /// output rectangle and the region (output plus halo, clamped to the window) it reads; with
    /// `stem_given` (a frame-local stem's features computed on whole frames) the halo leaves out
    /// the stem's reach.
    pub(super) fn tiles(
        &self,
        win: &AlignedWindow,
        rows: Range<usize>,
        stem_given: bool,
    ) -> Vec<Tile> {
        let c = win.centre();
        let (w, h) = (c.color.width(), c.color.height());
        // with a frame-local stem's features given, the stem's reach is already computed
        let halo = if stem_given {
            self.denoiser.receptive_radius_after_stem()
        } else {
            self.denoiser.receptive_radius()
        };
        // multi-scale kernels: regions on the coarsest scale's grid
        let g = self.denoiser.tile_grid();
        let (tw, th) = match (halo, self.tile) {
            (Some(_), tile) if tile > 0 => {
                let tile = (tile / g * g).max(g);
                (tile.min(w), tile.min(h))
            }
            _ => (w, h), // whole frame: UNets, or tiling switched off
        };
        let halo = halo.unwrap_or(0);
        let mut tiles = Vec::new();
        for y0 in rows.clone().step_by(th) {
            let y1 = (y0 + th).min(rows.end);
            for x0 in (0..w).step_by(tw) {
                let x1 = (x0 + tw).min(w);
                // rows that start or end off the grid (a band's, or the input blend's wider
                // rows) read from the grid row before and to the one after: the same region a
                // whole frame's tile reads there (the halo is a multiple of the grid)
                tiles.push(Tile {
                    x: x0..x1,
                    y: y0..y1,
                    region: Region {
                        x0: x0.saturating_sub(halo),
                        y0: (y0 / g * g).saturating_sub(halo),
                        x1: (x1 + halo).min(w),
                        y1: (y1.div_ceil(g) * g + halo).min(h),
                    },
                });
            }
        }
        tiles
    }

    /// One network call on tiles whose regions have the same size; their output rectangles
    /// are written into `out` (rows relative to `rows.start`, created on first use).
    #[allow(clippy::too_many_arguments)]
    fn run_group(
        &self,
        win: &AlignedWindow,
        stems: Option<&WindowStems>,
        scales: FeatureScales,
        group: &[Tile],
        values: &impl Fn(Region) -> Vec<f32>,
        chans: usize,
        f: &impl Fn(&crate::model::Prediction, GuideWeights, Tensor<5>, &Tensor<5>) -> Tensor<4>,
        out: &mut Option<Plane>,
        w: usize,
        rows: &Range<usize>,
    ) {
        let t = win.frames.len();
        let b = group.len();
        let (rw, rh) = group[0].region.size();
        let (feats, vals, stem) = timed(Stage::Inputs, || {
            let mut feats = Vec::new();
            let mut vals = Vec::new();
            let mut stem = Vec::new();
            for tile in group {
                if let Some(stems) = stems {
                    // the region's rows of every frame's warped features
                    let r = tile.region;
                    let band = timed(Stage::Align, || stems.rows(r.y0..r.y1));
                    let local = Region {
                        y0: 0,
                        y1: r.y1 - r.y0,
                        ..r
                    };
                    for plane in band.iter() {
                        local.crop(plane, &mut stem);
                    }
                }
                feats.extend(network_input(
                    win,
                    scales,
                    tile.region,
                    &self.denoiser.config.inputs,
                ));
                vals.extend(values(tile.region));
            }
            (feats, vals, stem)
        });
        let x = Tensor::<5>::from_data(
            TensorData::new(feats, [b, t, self.denoiser.config.input_channels(), rh, rw]),
            &self.device,
        );
        let v = Tensor::<5>::from_data(TensorData::new(vals, [b, t, chans, rh, rw]), &self.device);
        let (prediction, guides) = match stems {
            Some(_) => {
                let c = self.denoiser.stem_channels();
                let stem =
                    Tensor::<5>::from_data(TensorData::new(stem, [b, t, c, rh, rw]), &self.device);
                self.denoiser
                    .predict_with_stem(x.clone(), stem, self.threshold())
            }
            None => self.denoiser.predict_guided(x.clone(), self.threshold()),
        };
        let res = timed(Stage::Kernels, || f(&prediction, guides, v, &x));
        let oc = res.dims()[1];
        let res = res.to_data().try_to_vec::<f32>().expect("f32 output");
        let out = out.get_or_insert_with(|| Plane::zeros(w, rows.len(), oc));
        for (i, tile) in group.iter().enumerate() {
            let r = tile.region;
            let res = &res[i * oc * rw * rh..][..oc * rw * rh];
            for ch in 0..oc {
                for y in tile.y.clone() {
                    let src = &res[ch * rw * rh + (y - r.y0) * rw + (tile.x.start - r.x0)..]
                        [..tile.x.len()];
                    let at = (y - rows.start) * w;
                    out.channel_mut(ch)[at + tile.x.start..at + tile.x.end].copy_from_slice(src);
                }
            }
        }
    }
}

/// Splits `tiles` into runs of consecutive tiles whose regions have the same size, at most
/// `batch` long: the tiles that can share one network call.
pub(super) fn batches(tiles: &[Tile], batch: usize) -> Vec<Range<usize>> {
    let mut out: Vec<Range<usize>> = Vec::new();
    for (i, tile) in tiles.iter().enumerate() {
        match out.last_mut() {
            Some(r)
                if r.len() < batch.max(1) && tiles[r.start].region.size() == tile.region.size() =>
            {
                r.end = i + 1
            }
            _ => out.push(i..i + 1),
        }
    }
    out
}

/// One tile of a tiled run: the output rectangle it produces and the region it reads.
pub(super) struct Tile {
    x: Range<usize>,
    y: Range<usize>,
    pub(super) region: Region,
}
