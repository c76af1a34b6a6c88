//! Evaluations per second of every model (and NDF), printed by criterion as
//! throughput in elements per second. Run: `cargo bench -p brdf --bench models`.

use std::hint::black_box;

use brdf::catalog;
use brdf::ndf::{Beckmann, Ggx, MaskingOperator, Ndf, NdfGrid, NdfTable, TabulatedNdf};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use glam::Vec3;

const PAIRS: usize = 4096;

fn directions() -> Vec<(Vec3, Vec3)> {
    // A deterministic spread over the upper hemisphere (golden-angle spiral).
    let dir = |k: usize, n: usize| {
        let z = 1.0 - (k as f32 + 0.5) / n as f32;
        let r = (1.0 - z * z).sqrt();
        let p = k as f32 * 2.399_963;
        Vec3::new(r * p.cos(), r * p.sin(), z)
    };
    (0..PAIRS).map(|k| (dir(k, PAIRS), dir((k * 7919) % PAIRS, PAIRS))).collect()
}

fn bench_models(c: &mut Criterion) {
    let pairs = directions();
    let mut group = c.benchmark_group("eval");
    group.throughput(Throughput::Elements(PAIRS as u64));
    for e in catalog::models(0.2, 2.0, 0.3, 0.7, Some(NdfGrid::DEFAULT)) {
        group.bench_function(e.name, |b| {
            b.iter(|| {
                let mut acc = Vec3::ZERO;
                for &(i, o) in &pairs {
                    acc += e.brdf.eval(black_box(i), black_box(o));
                }
                acc
            })
        });
    }
    group.finish();

    let mut group = c.benchmark_group("ndf");
    group.throughput(Throughput::Elements(PAIRS as u64));
    let grid = NdfGrid::DEFAULT;
    let mut table = NdfTable::from_ndf(grid, &Beckmann::new(0.2, 0.4, 0.3));
    table.normalize();
    let ndfs: Vec<(&str, Box<dyn Ndf>)> = vec![
        ("beckmann", Box::new(Beckmann::new(0.2, 0.4, 0.3))),
        ("ggx", Box::new(Ggx::new(0.2, 0.4, 0.3))),
        ("tabulated", Box::new(TabulatedNdf::new(table.clone(), &MaskingOperator::new(grid)))),
    ];
    for (name, n) in &ndfs {
        group.bench_function(format!("{name}_d_and_sigma"), |b| {
            b.iter(|| {
                let mut acc = 0.0f32;
                for &(h, v) in &pairs {
                    acc += n.d(black_box(h)) + n.projected_area(black_box(v));
                }
                acc
            })
        });
    }
    group.finish();

    let op = MaskingOperator::new(grid);
    let mut group = c.benchmark_group("table");
    group.throughput(Throughput::Elements(1));
    group.bench_function("masking_by_fft_32x96", |b| b.iter(|| op.projected_areas(black_box(&table))));
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20).warm_up_time(std::time::Duration::from_millis(300)).measurement_time(std::time::Duration::from_secs(1));
    targets = bench_models
}
criterion_main!(benches);
