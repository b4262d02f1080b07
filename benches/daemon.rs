//! shimmyd cost: the whole daemon pipeline (log reader → Mapper → event stage → journal) on the
//! real RAV4 log replayed with `--fast`, through `shimmy::daemon::run::run` with the stage the
//! binary uses. Reports frames/s; the CPU share of one core at a bus load of 8,000 frames/s is
//! 8,000 divided by that rate (the loop is single-threaded). Journal fsync is `always`, but the
//! RAV4 log has no braking events, so the journal gets only its start and stop records.
//!
//! Run: `cargo bench --bench daemon` (needs the shared data; see docs/BENCHMARKS.md).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use shimmy::daemon::run::{run, Options};

fn bench(c: &mut Criterion) {
    let Some((log, dbc)) = shimmy::shared_data::require_rav4() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("shimmyd.toml");
    let mapping = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("config/vehicles/toyota_rav4/mapping.toml");
    std::fs::write(
        &cfg,
        format!(
            "[input]\ndbc = {dbc:?}\nmapping = {mapping:?}\n[outputs]\njournal_dir = \"journal\"\nstate_dir = \"state\"\n"
        ),
    )
    .unwrap();
    let mut g = c.benchmark_group("shimmyd");
    g.throughput(Throughput::Elements(53_800));
    g.sample_size(20);
    g.bench_function("replay_fast_rav4_53800_frames", |b| {
        b.iter(|| {
            run(
                Options {
                    config: cfg.clone(),
                    replay: vec![log.clone()],
                    fast: true,
                    ..Options::default()
                },
                &shimmy::daemon::stage::for_config,
            )
            .unwrap()
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
