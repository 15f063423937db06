use super::*;

/// Albedo, normal and depth of a textured scene seen moved by `(dx, dy)` pixels, colour noisy.
fn scene(w: usize, h: usize, (dx, dy): (f32, f32), seed: u32) -> Frame {
    let tex = |x: f32, y: f32, c: usize| -> f32 {
        let k = c as f32;
        0.5 + 0.2 * (0.13 * x + 0.9 * k).sin() * (0.09 * y - 0.4 * k).cos()
            + 0.15 * (0.37 * x + 0.21 * y + k).sin()
    };
    let at = |x: usize, y: usize| (x as f32 - dx, y as f32 - dy);
    let mut noise = seed.wrapping_mul(2_654_435_761).max(1);
    let mut next = move || {
        noise ^= noise << 13;
        noise ^= noise >> 17;
        noise ^= noise << 5;
        (noise as f32 / u32::MAX as f32) - 0.5
    };
    let color = Plane::from_vec(
        w,
        h,
        3,
        (0..3 * w * h)
            .map(|i| {
                let (c, p) = (i / (w * h), i % (w * h));
                let (x, y) = at(p % w, p / w);
                (tex(x, y, c) * (1.0 + 0.6 * next())).max(0.0)
            })
            .collect(),
    );
    let mut f = Frame::synthetic(color);
    f.albedo = Some(Plane::from_fn(w, h, 3, |x, y, c| {
        let (x, y) = at(x, y);
        tex(x, y, c)
    }));
    f.normal = Some(Plane::from_fn(w, h, 3, |x, y, c| {
        let (x, y) = at(x, y);
        [0.3 * (0.05 * x).sin(), 0.3 * (0.04 * y).cos(), 0.9][c]
    }));
    f.depth = Some(Plane::from_fn(w, h, 1, |x, y, _| {
        let (x, y) = at(x, y);
        4.0 + (0.03 * x + 0.02 * y).sin()
    }));
    f
}

fn worst_error(flow: &Plane, (dx, dy): (f32, f32), margin: usize) -> f32 {
    let mut worst = 0f32;
    for y in margin..flow.height() - margin {
        for x in margin..flow.width() - margin {
            worst = worst.max((flow.get(x, y, 0) - dx).hypot(flow.get(x, y, 1) - dy));
        }
    }
    worst
}

#[test]
fn the_downsampling_factor_keeps_the_signal_within_its_pixel_budget() {
    let p = EstimateParams {
        max_pixels: 1000,
        ..EstimateParams::default()
    };
    let s = MotionSignal::of_frame(&scene(100, 41, (0.0, 0.0), 1), &p);
    assert_eq!(s.factor, 3, "4100 pixels need a factor of 3 for 1000");
    assert_eq!((s.plane.width(), s.plane.height()), (34, 14));
    assert_eq!(s.plane.channels(), 8, "luminance, albedo, normal, depth");
    let alone = MotionSignal::of_frame(&Frame::synthetic(Plane::filled(10, 10, 3, 1.0)), &p);
    assert_eq!((alone.factor, alone.plane.channels()), (1, 1));
}

#[test]
fn a_signal_built_band_by_band_equals_the_whole_frames() {
    let p = EstimateParams {
        max_pixels: 900,
        ..EstimateParams::default()
    };
    let f = scene(60, 50, (1.0, 2.0), 3);
    let whole = MotionSignal::of_frame(&f, &p);
    let mut b = SignalBuilder::new(60, 50, &p);
    for y0 in (0..50).step_by(7) {
        b.add_rows(y0, &f.rows(y0..(y0 + 7).min(50)));
    }
    assert_eq!(b.finish().plane, whole.plane);
}

#[test]
fn motion_between_shifted_frames_is_found_in_both_directions_in_frame_pixels() {
    let (w, h) = (160, 120);
    let shift = (2.6f32, -1.4f32);
    // the later frame shows the scene moved by `shift`
    let p = EstimateParams {
        max_pixels: w * h / 4,
        ..EstimateParams::default()
    };
    let a = MotionSignal::of_frame(&scene(w, h, (0.0, 0.0), 1), &p);
    let b = MotionSignal::of_frame(&scene(w, h, shift, 2), &p);
    assert_eq!(a.factor, 2);
    let m = PairMotion::estimate(&a, &b, &p);
    let fwd = m.rows(true, 0..h);
    let bwd = m.rows(false, 0..h);
    let e_fwd = worst_error(&fwd, shift, 12);
    let e_bwd = worst_error(&bwd, (-shift.0, -shift.1), 12);
    assert!(e_fwd < 0.06 && e_bwd < 0.06, "{e_fwd} {e_bwd} px");
    assert!(m.same_shot(&p), "matched {}", m.matched);
    assert!(m.matched > 0.8, "matched {}", m.matched);
    // band rows equal the whole frame's rows
    assert_eq!(m.rows(true, 30..50), fwd.rows(30..50));
}

#[test]
fn frames_of_two_unrelated_shots_are_told_apart() {
    let (w, h) = (128, 96);
    let p = EstimateParams::default();
    let a = scene(w, h, (0.0, 0.0), 1);
    let mut b = scene(w, h, (0.0, 0.0), 2);
    // another scene: other albedo pattern, other normals, other depth
    b.albedo = Some(Plane::from_fn(w, h, 3, |x, y, c| {
        0.5 + 0.4 * ((x / 9 + y / 7 + c) % 2) as f32 - 0.2
    }));
    b.normal = Some(Plane::from_fn(w, h, 3, |x, _, c| {
        [0.8 * (0.2 * x as f32).cos(), 0.0, 0.5][c]
    }));
    b.depth = Some(Plane::from_fn(w, h, 1, |x, y, _| {
        1.0 + 0.05 * (x + y) as f32
    }));
    let m = PairMotion::estimate(
        &MotionSignal::of_frame(&a, &p),
        &MotionSignal::of_frame(&b, &p),
        &p,
    );
    assert!(!m.same_shot(&p), "matched {}", m.matched);
    let same = PairMotion::estimate(
        &MotionSignal::of_frame(&a, &p),
        &MotionSignal::of_frame(&scene(w, h, (0.7, 0.3), 5), &p),
        &p,
    );
    assert!(same.same_shot(&p), "matched {}", same.matched);
}
