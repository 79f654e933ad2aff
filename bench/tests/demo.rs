//! The Fig. 3 example: a larger rho removes more points wrongly (it bridges the notch), and the critic trained on
//! the result still finds the true set.

use cabc_bench::demo::autolabel_demo;

#[test]
fn fig3_demo_runs_and_smaller_rho_removes_fewer_points_wrongly() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("fig3.png");
    let report = autolabel_demo(&[0.6, 0.15], 0, &png).unwrap();
    assert!(std::fs::metadata(&png).unwrap().len() > 10_000);
    let (big, small) = (&report.panels[0], &report.panels[1]);
    assert!(big.removed_wrongly > small.removed_wrongly, "{report:?}");
    assert!(small.removed_correctly > 100, "{report:?}");
    // The critic's accuracy on the grid after training (issue 29): 0.974 under this machine's AVX2 kernels and
    // 0.969 under the oldest (ATEN_CPU_CAPABILITY=default, MKL_ENABLE_INSTRUCTIONS=AVX); the kernels move it by
    // 0.005, the margin to 0.9 is 0.07.
    assert!(small.accuracy > 0.9, "{report:?}");
    println!("{}", serde_json::to_string_pretty(&report).unwrap());
}
