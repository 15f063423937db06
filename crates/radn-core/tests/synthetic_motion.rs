//! Alignment against analytic motion: translation, rotation, and a moving object over a static
//! background. Warped side frames must match the centre frame within 1e-3 wherever the surface
//! is visible in both, and confidence must be ~0 exactly where it is not.

use radn_core::align::warp::Resampling;
use radn_core::align::{align_bands, align_window, AlignParams, AlignedWindow};
use radn_core::io::frame::Frame;
use radn_core::run::banding::{
    frame_bands, hop_reach, window_band_rows, MotionReach, ALIGNMENT_EDGE_ROWS,
};
use radn_core::Plane;

const W: usize = 96;
const H: usize = 72;

/// A smooth texture (bilinear interpolation error below 1e-3).
fn texture(u: f32, v: f32) -> [f32; 3] {
    let a = 0.5 + 0.2 * (0.10 * u + 0.07 * v).sin() + 0.15 * (0.09 * v - 0.05 * u).cos();
    let b = 0.4 + 0.2 * (0.06 * u - 0.08 * v).cos();
    let c = 0.3 + 0.1 * (0.05 * (u + v)).sin();
    [a, b, c]
}

/// The geometry seen by pixel (x, y) of frame t: world texture coordinates, albedo tint,
/// depth, and the displacements to the previous and the next frame.
struct Sample {
    uv: (f32, f32),
    tint: f32,
    depth: f32,
    prev: (f32, f32),
    next: (f32, f32),
}

fn render(t: i32, scene: &dyn Fn(f32, f32, i32) -> Sample) -> Frame {
    let mut color = Plane::zeros(W, H, 3);
    let mut albedo = Plane::zeros(W, H, 3);
    let mut normal = Plane::zeros(W, H, 3);
    let mut depth = Plane::zeros(W, H, 1);
    let mut mp = Plane::zeros(W, H, 2);
    let mut mn = Plane::zeros(W, H, 2);
    for y in 0..H {
        for x in 0..W {
            let s = scene(x as f32, y as f32, t);
            let c = texture(s.uv.0, s.uv.1);
            for k in 0..3 {
                color.set(x, y, k, c[k] * s.tint);
                albedo.set(x, y, k, s.tint * [0.8, 0.6, 0.4][k]);
            }
            normal.set(x, y, 2, 1.0);
            depth.set(x, y, 0, s.depth);
            mp.set(x, y, 0, s.prev.0);
            mp.set(x, y, 1, s.prev.1);
            mn.set(x, y, 0, s.next.0);
            mn.set(x, y, 1, s.next.1);
        }
    }
    let mut f = Frame::synthetic(color);
    f.albedo = Some(albedo);
    f.normal = Some(normal);
    f.depth = Some(depth);
    f.motion_prev = Some(mp);
    f.motion_next = Some(mn);
    f
}

fn align(scene: &dyn Fn(f32, f32, i32) -> Sample, mix: bool) -> AlignedWindow {
    let frames: Vec<Frame> = (-2..=2).map(|t| render(t, scene)).collect();
    let window: Vec<Option<&Frame>> = frames.iter().map(Some).collect();
    let params = AlignParams {
        mix_centre: mix,
        ..AlignParams::default()
    };
    align_window(&window, &params)
}

/// Checks every side frame: where `visible(x, y, offset)` the warp matches the centre within
/// 1e-3 and confidence is high; where `hidden(...)` confidence is ~0. Returns pixel counts.
fn check(
    win: &AlignedWindow,
    visible: &dyn Fn(f32, f32, i32) -> bool,
    hidden: &dyn Fn(f32, f32, i32) -> bool,
) -> (usize, usize) {
    let centre = &win.centre().color;
    let (mut nv, mut nh) = (0, 0);
    for f in &win.frames {
        if f.offset == 0 {
            continue;
        }
        for y in 0..H {
            for x in 0..W {
                let (xf, yf) = (x as f32, y as f32);
                if visible(xf, yf, f.offset) {
                    nv += 1;
                    for c in 0..3 {
                        let d = (f.color.get(x, y, c) - centre.get(x, y, c)).abs();
                        assert!(
                            d < 1e-3,
                            "offset {} pixel ({x},{y}) channel {c}: warp error {d}",
                            f.offset
                        );
                    }
                    let conf = f.confidence.get(x, y, 0);
                    assert!(
                        conf > 0.9,
                        "offset {} pixel ({x},{y}): confidence {conf} where the surface is visible",
                        f.offset
                    );
                } else if hidden(xf, yf, f.offset) {
                    nh += 1;
                    let conf = f.confidence.get(x, y, 0);
                    assert!(
                        conf < 0.02,
                        "offset {} pixel ({x},{y}): confidence {conf} where the surface is hidden",
                        f.offset
                    );
                }
            }
        }
    }
    (nv, nh)
}

fn inside(x: f32, y: f32, margin: f32) -> bool {
    x >= margin && y >= margin && x <= W as f32 - 1.0 - margin && y <= H as f32 - 1.0 - margin
}

#[test]
fn translation() {
    let v = (1.75f32, -0.6f32); // the camera pans: the image moves by -v per frame
    let scene = move |x: f32, y: f32, t: i32| Sample {
        uv: (x + v.0 * t as f32, y + v.1 * t as f32),
        tint: 1.0,
        depth: 4.0,
        prev: v,
        next: (-v.0, -v.1),
    };
    let win = align(&scene, false);
    let src = |x: f32, y: f32, o: i32| (x - v.0 * o as f32, y - v.1 * o as f32);
    let visible = |x: f32, y: f32, o: i32| {
        let (sx, sy) = src(x, y, o);
        inside(sx, sy, 0.0)
    };
    let hidden = |x: f32, y: f32, o: i32| {
        let (sx, sy) = src(x, y, o);
        !inside(sx, sy, -1.0)
    };
    let (nv, nh) = check(&win, &visible, &hidden);
    assert!(nv > 20000 && nh > 500, "{nv} visible, {nh} off-screen");
}

#[test]
fn rotation() {
    let a = 0.03f32; // radians per frame about the image centre
    let (cx, cy) = (W as f32 / 2.0, H as f32 / 2.0);
    let rot = move |x: f32, y: f32, ang: f32| {
        let (dx, dy) = (x - cx, y - cy);
        (
            cx + ang.cos() * dx - ang.sin() * dy,
            cy + ang.sin() * dx + ang.cos() * dy,
        )
    };
    // pixel p of frame t shows world point R(a t) p; in frame s that point is at R(-a s) R(a t) p
    let scene = move |x: f32, y: f32, t: i32| {
        let uv = rot(x, y, a * t as f32);
        let p = rot(x, y, a);
        let n = rot(x, y, -a);
        Sample {
            uv,
            tint: 1.0,
            depth: 4.0,
            prev: (p.0 - x, p.1 - y),
            next: (n.0 - x, n.1 - y),
        }
    };
    let win = align(&scene, false);
    let visible = |x: f32, y: f32, o: i32| {
        let s = rot(x, y, -a * o as f32);
        inside(s.0, s.1, 0.0)
    };
    let hidden = |x: f32, y: f32, o: i32| {
        let s = rot(x, y, -a * o as f32);
        !inside(s.0, s.1, -1.0)
    };
    let (nv, nh) = check(&win, &visible, &hidden);
    assert!(nv > 20000 && nh > 300, "{nv} visible, {nh} off-screen");
}

const DISC_R: f32 = 14.0;
const DISC_V: (f32, f32) = (4.0, 1.5);

fn disc_centre(t: i32) -> (f32, f32) {
    (40.0 + DISC_V.0 * t as f32, 34.0 + DISC_V.1 * t as f32)
}

fn in_disc(x: f32, y: f32, t: i32) -> f32 {
    let c = disc_centre(t);
    ((x - c.0).powi(2) + (y - c.1).powi(2)).sqrt() - DISC_R
}

/// A textured disc moving by `DISC_V` per frame over a static textured wall. The background
/// does not move, but where the disc covers it in another frame, that frame's motion is the
/// disc's.
fn disc_scene(x: f32, y: f32, t: i32) -> Sample {
    if in_disc(x, y, t) < 0.0 {
        let c = disc_centre(t);
        Sample {
            uv: (x - c.0 + 500.0, y - c.1 + 300.0),
            tint: 0.6,
            depth: 2.0,
            prev: (-DISC_V.0, -DISC_V.1),
            next: DISC_V,
        }
    } else {
        Sample {
            uv: (x, y),
            tint: 1.0,
            depth: 5.0,
            prev: (0.0, 0.0),
            next: (0.0, 0.0),
        }
    }
}

#[test]
fn moving_object_over_static_background() {
    let scene = disc_scene;
    let win = align(&scene, false);
    // a pixel of the centre frame is visible in frame `o` if the same surface is there; keep 2 px
    // away from the disc's silhouettes in both frames, where bilinear lookups mix surfaces
    let visible = |x: f32, y: f32, o: i32| {
        let here = in_disc(x, y, 0);
        if here.abs() < 2.0 {
            return false;
        }
        let (sx, sy) = if here < 0.0 {
            (x + DISC_V.0 * o as f32, y + DISC_V.1 * o as f32)
        } else {
            (x, y)
        };
        if !inside(sx, sy, 0.0) {
            return false;
        }
        let there = in_disc(sx, sy, o);
        if here < 0.0 {
            there < -2.0
        } else {
            there > 2.0 && (1..o.abs()).all(|k| in_disc(x, y, o.signum() * k) > 2.0)
        }
    };
    // background pixels that the disc covered in frame `o`: disoccluded, must get ~0
    let hidden = |x: f32, y: f32, o: i32| in_disc(x, y, 0) > 1.5 && in_disc(x, y, o) < -1.5;
    let (nv, nh) = check(&win, &visible, &hidden);
    assert!(nv > 20000 && nh > 200, "{nv} visible, {nh} disoccluded");
}

#[test]
fn centre_mixing_replaces_hidden_pixels_with_the_centre() {
    let scene = disc_scene;
    let win = align(&scene, true);
    let centre = &win.centre().color;
    let mut n = 0;
    for f in win.frames.iter().filter(|f| f.offset != 0) {
        for y in 0..H {
            for x in 0..W {
                if in_disc(x as f32, y as f32, 0) > 1.5
                    && in_disc(x as f32, y as f32, f.offset) < -1.5
                {
                    n += 1;
                    for c in 0..3 {
                        assert!((f.color.get(x, y, c) - centre.get(x, y, c)).abs() < 0.02);
                    }
                }
            }
        }
    }
    assert!(n > 200, "{n}");
}

#[test]
fn window_is_clamped_at_sequence_ends() {
    let scene = |x: f32, y: f32, _t: i32| Sample {
        uv: (x, y),
        tint: 1.0,
        depth: 3.0,
        prev: (0.0, 0.0),
        next: (0.0, 0.0),
    };
    let frames: Vec<Frame> = (0..3).map(|t| render(t, &scene)).collect();
    // centre is the first frame of the sequence: offsets -2 and -1 do not exist
    let window = vec![
        None,
        None,
        Some(&frames[0]),
        Some(&frames[1]),
        Some(&frames[2]),
    ];
    let win = align_window(&window, &AlignParams::default());
    for f in &win.frames[..2] {
        assert!(f.confidence.data().iter().all(|&c| c == 0.0));
        assert_eq!(f.color, win.centre().color);
    }
    assert!(win.frames[3].confidence.data().iter().all(|&c| c > 0.99));
    assert_eq!(
        radn_core::align::window_indices(0, 3, 2),
        vec![None, None, Some(0), Some(1), Some(2)]
    );
    assert_eq!(
        radn_core::align::window_indices(4, 5, 2),
        vec![Some(2), Some(3), Some(4), None, None]
    );
}

/// Scatters one-pixel fireflies (×300 in colour and albedo, as Cycles writes them) over frame
/// `t`, at places that differ from frame to frame.
fn add_fireflies(f: &mut Frame, t: usize) {
    for y in 0..H {
        for x in 0..W {
            if (x * 7 + y * 13 + t * 5).is_multiple_of(89) {
                for c in 0..3 {
                    let v = f.color.get(x, y, c);
                    f.color.set(x, y, c, 300.0 * v);
                    let a = f.albedo.as_ref().unwrap().get(x, y, c);
                    f.albedo.as_mut().unwrap().set(x, y, c, 300.0 * a);
                }
            }
        }
    }
}

/// A one-pixel firefly of the centre frame (in colour, albedo and AOVs, as Cycles writes it)
/// must not reach the side frames: it zeroes their confidence around it, and centre mixing must
/// then copy a clamped value, not the firefly. The AOVs must still sum to the colour in every
/// frame after mixing.
#[test]
fn a_centre_firefly_stays_in_the_centre_frame() {
    let scene = disc_scene;
    let mut frames: Vec<Frame> = (-2..=2).map(|t| render(t, &scene)).collect();
    for f in &mut frames {
        // two AOVs that sum to the colour
        for (k, share) in [0.3f32, 0.7].iter().enumerate() {
            let mut plane = f.color.clone();
            plane.data_mut().iter_mut().for_each(|v| *v *= share);
            f.aovs.push(radn_core::io::frame::Aov {
                name: format!("part{k}"),
                channels: ["R", "G", "B"].map(|c| format!("part{k}.{c}")).to_vec(),
                plane,
            });
        }
    }
    let clean: Vec<Frame> = frames.clone();
    // fireflies in the centre frame: one on the wall seen by every frame, and one on the wall
    // next to the disc, where the disc hides the wall two frames later
    let seen = (12usize, 60usize);
    let hidden = (57usize, 36usize);
    assert!(in_disc(hidden.0 as f32, hidden.1 as f32, 0) > 3.0);
    assert!(in_disc(hidden.0 as f32, hidden.1 as f32, 2) < -1.5);
    let centre = &mut frames[2];
    for (x, y) in [seen, hidden] {
        for c in 0..3 {
            let v = centre.color.get(x, y, c);
            centre.color.set(x, y, c, 500.0 * v);
            let a = centre.albedo.as_ref().unwrap().get(x, y, c);
            centre.albedo.as_mut().unwrap().set(x, y, c, 500.0 * a);
            for aov in &mut centre.aovs {
                let v = aov.plane.get(x, y, c);
                aov.plane.set(x, y, c, 500.0 * v);
            }
        }
    }
    let params = AlignParams::default();
    let with = align_window(&frames.iter().map(Some).collect::<Vec<_>>(), &params);
    let without = align_window(&clean.iter().map(Some).collect::<Vec<_>>(), &params);
    let mut untrusted = 0;
    for (f, g) in with.frames.iter().zip(&without.frames) {
        if f.offset == 0 {
            continue;
        }
        // around each firefly a side frame carries at most a few times what it carries without
        for (px, py) in [seen, hidden] {
            for (x, y) in (py - 1..=py + 1).flat_map(|y| (px - 1..=px + 1).map(move |x| (x, y))) {
                if f.confidence.get(x, y, 0) < 0.5 {
                    untrusted += 1;
                }
                for c in 0..3 {
                    let (v, clean) = (f.color.get(x, y, c), g.color.get(x, y, c));
                    assert!(
                        v <= 5.0 * clean,
                        "offset {}: ({x},{y}) carries {v}, {clean} without the firefly",
                        f.offset
                    );
                }
            }
        }
        // the AOVs still sum to the colour
        for (i, v) in f.color.data().iter().enumerate() {
            let sum: f32 = f.aovs.iter().map(|a| a.data()[i]).sum();
            assert!(
                (sum - v).abs() <= 1e-4 * v.abs().max(1.0),
                "offset {}",
                f.offset
            );
        }
    }
    // the side frames were untrusted around the fireflies: centre mixing was exercised
    assert!(untrusted >= 20, "{untrusted}");
    assert!(with.frames[4].confidence.get(hidden.0, hidden.1, 0) < 0.5);
}

/// What a pixel of frame t sees.
type Scene = dyn Fn(f32, f32, i32) -> Sample;

/// Banded alignment reads of each frame only the rows a band of the centre frame reaches
/// along the motion; on the band's rows (`ALIGNMENT_EDGE_ROWS` in from a cut that is not a
/// frame edge) it
/// must give what whole-frame alignment gives, with native and inverted motion, vertical motion
/// of several pixels per frame, and windows clamped at the sequence's start, with either
/// resampling (Catmull-Rom reads a row more on each side).
#[test]
fn banded_alignment_equals_whole_frame_alignment() {
    let pan = |x: f32, y: f32, t: i32| Sample {
        uv: (x + 0.7 * t as f32, y - 3.4 * t as f32),
        tint: 1.0,
        depth: 4.0,
        prev: (0.7, -3.4),
        next: (-0.7, 3.4),
    };
    let scenes: [(&str, &Scene); 2] = [("pan", &pan), ("disc", &disc_scene)];
    let mut compared = 0usize;
    let resamplings = [Resampling::Bilinear, Resampling::CatmullRom];
    for (name, scene, resampling) in scenes
        .into_iter()
        .flat_map(|(n, s)| resamplings.map(move |r| (n, s, r)))
    {
        for fields in ["both", "prev only", "next only"] {
            for start in [false, true] {
                let mut frames: Vec<Frame> = (-2..=2).map(|t| render(t, scene)).collect();
                for (t, f) in frames.iter_mut().enumerate() {
                    // fireflies, some next to a band cut, exercise the guides' firefly clamp
                    add_fireflies(f, t);
                    match fields {
                        "prev only" => f.motion_next = None,
                        "next only" => f.motion_prev = None,
                        _ => {}
                    }
                }
                let window: Vec<Option<&Frame>> = frames
                    .iter()
                    .enumerate()
                    .map(|(k, f)| (!start || k >= 2).then_some(f))
                    .collect();
                let params = AlignParams {
                    resampling,
                    ..AlignParams::default()
                };
                let whole = align_window(&window, &params);
                let reach: Vec<Option<MotionReach>> =
                    window.iter().map(|f| f.map(MotionReach::of)).collect();
                let hops = hop_reach(&reach);
                assert!(hops[4] >= 4 || name != "pan", "{hops:?}");
                for y0 in (0..H).step_by(13) {
                    let y1 = (y0 + 13).min(H);
                    let centre =
                        y0.saturating_sub(ALIGNMENT_EDGE_ROWS)..(y1 + ALIGNMENT_EDGE_ROWS).min(H);
                    let rows = window_band_rows(centre.clone(), &hops, H);
                    let crops: Vec<Option<Frame>> = window
                        .iter()
                        .zip(&rows)
                        .map(|(f, r)| f.map(|f| f.rows(r.clone())))
                        .collect();
                    let bands = frame_bands(&crops, &rows, H);
                    let banded = align_bands(&bands, &params);
                    for (a, b) in whole.frames.iter().zip(&banded.frames) {
                        let pairs = [
                            (&a.color, &b.color),
                            (&a.confidence, &b.confidence),
                            (&a.flow, &b.flow),
                            (a.albedo.as_ref().unwrap(), b.albedo.as_ref().unwrap()),
                            (a.normal.as_ref().unwrap(), b.normal.as_ref().unwrap()),
                            (a.depth.as_ref().unwrap(), b.depth.as_ref().unwrap()),
                        ];
                        for (pw, pb) in pairs {
                            assert_eq!(pb.height(), centre.len());
                            for y in y0..y1 {
                                for c in 0..pw.channels() {
                                    for x in 0..W {
                                        let (u, v) =
                                            (pw.get(x, y, c), pb.get(x, y - centre.start, c));
                                        assert!(
                                            (u - v).abs() <= 1e-5,
                                            "{name}, {resampling:?}, {fields}, start {start}: frame {} \
                                             row {y} x {x} channel {c}: whole {u}, banded {v}",
                                            a.offset
                                        );
                                        compared += 1;
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
    }
    assert!(compared > 2_000_000, "{compared}");
}
