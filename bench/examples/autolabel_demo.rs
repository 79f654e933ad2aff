//! `cargo run --release -p cabc-bench --example autolabel_demo -- OUT.png [rho ...]`:
//! the paper's Fig. 3 without building the `cabc` binary (or `cabc demo`).

use cabc_bench::demo::autolabel_demo;

fn main() {
    let mut args = std::env::args().skip(1);
    let out = args.next().unwrap_or_else(|| "autolabel-demo.png".into());
    let mut rhos: Vec<f64> = args.filter_map(|a| a.parse().ok()).collect();
    if rhos.is_empty() {
        rhos = vec![0.5, 0.25, 0.1];
    }
    let report = autolabel_demo(&rhos, 0, std::path::Path::new(&out)).expect("demo");
    println!(
        "{}",
        serde_json::to_string_pretty(&report).expect("serialises")
    );
}
