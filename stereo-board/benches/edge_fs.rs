//! One Edge-FS frame on the host, default and paper configurations.
//!
//! `cargo bench -p stereo-board --bench edge_fs` prints criterion's time per frame and the
//! resulting frames per second. Frames are a synthetic textured scene moving between frames
//! (so every matcher does real work); the history is warm.
// criterion_main! generates an undocumented `main`.
#![allow(missing_docs)]

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use protocol::{GyroAttitude, STEREO_FRAME_BYTES};
use std::time::Instant;
use stereo_board::edge_fs::{EdgeFs, EdgeFsParams};

/// Eight frames of a textured wall approaching the camera, with some yaw.
fn frames() -> Vec<Box<[u8; STEREO_FRAME_BYTES]>> {
    (0..8)
        .map(|k| {
            let mut f = Box::new([0u8; STEREO_FRAME_BYTES]);
            let scale = 1.0 + 0.02 * k as f32;
            for r in 0..96 {
                for c in 0..128 {
                    let x = (c as f32 - 64.0) * scale + k as f32;
                    let tex = |x: f32| {
                        let v = (x * 0.37).sin() * 60.0 + (x * 0.11 + r as f32 * 0.05).cos() * 50.0;
                        (128.0 + v) as u8
                    };
                    f[2 * (r * 128 + c)] = tex(x + 3.0);
                    f[2 * (r * 128 + c) + 1] = tex(x);
                }
            }
            f
        })
        .collect()
}

fn bench_config(c: &mut Criterion, name: &str, mut params: EdgeFsParams) {
    params.stereo_shift_px = 2;
    let frames = frames();
    let mut fs = EdgeFs::new(params);
    let mut t_us = 0u64;
    let mut step = |fs: &mut EdgeFs, k: usize| {
        t_us += 40_000;
        let g = GyroAttitude {
            timestamp_us: protocol::WireTime(t_us as u32),
            rates_radps: [0.0; 3],
            attitude_rad: [0.0, 0.0, 0.001 * k as f32],
        };
        fs.process(
            &frames[k % frames.len()],
            timebase::Instant::from_micros(t_us),
            Some(&g),
        )
    };
    for k in 0..16 {
        step(&mut fs, k);
    }
    let mut k = 16;
    c.bench_function(&format!("edge_fs_frame_{name}"), |b| {
        b.iter(|| {
            k += 1;
            black_box(step(&mut fs, k))
        })
    });
    // Frames per second over a plain timed loop.
    let n = 2000;
    let start = Instant::now();
    for j in 0..n {
        black_box(step(&mut fs, j));
    }
    let fps = n as f64 / start.elapsed().as_secs_f64();
    println!("edge_fs {name}: {fps:.0} frames/s on this host");
}

fn edge_fs(c: &mut Criterion) {
    bench_config(c, "default", EdgeFsParams::default_config());
    bench_config(c, "paper", EdgeFsParams::paper());
}

criterion_group!(benches, edge_fs);
criterion_main!(benches);
