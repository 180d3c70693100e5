//! Criterion microbenchmarks of the forest core (split search, traversal). Filled in by the
//! forest work; kept compiling so `cargo bench` runs from the root.
use criterion::{criterion_group, criterion_main, Criterion};

fn version(c: &mut Criterion) {
    c.bench_function("noop", |b| b.iter(|| isa_core::VERSION.len()));
}

criterion_group!(benches, version);
criterion_main!(benches);
