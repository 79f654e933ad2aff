//! `cargo run --release -p cabc-bench --example bench [n_plus n_uncertain n_train]`:
//! the `cabc bench` figures without building the `cabc` binary.

use cabc_bench::throughput::{run_bench, BenchOptions};

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let mut o = BenchOptions::default();
    if let [p, u, t, ..] = args[..] {
        (o.n_plus, o.n_uncertain, o.n_train) = (p, u, t);
    }
    let report = run_bench(&o);
    println!(
        "{}",
        serde_json::to_string_pretty(&report).expect("serialises")
    );
}
