//! The plan files in deploy/campaign/ are the bash campaign's slices, translated: `issue-18`'s expanded list is, line
//! for line, what `deploy/campaign.sh --plan issue-18 --list` printed before the translation (the fixtures, captured
//! from it); `recipe`, a campaign still growing, keeps the slices the bash lanes ran (its first 14) word for word,
//! since a slice's text names its claim and an equal text keeps those claims valid.

use cabc_campaign::{list, plans_in, Plan};
use std::path::Path;

fn root() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
}

fn fixture(name: &str) -> String {
    std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures")
            .join(name),
    )
    .unwrap()
}

fn plan(name: &str) -> Plan {
    Plan::load(&cabc_campaign::plan::plan_path(root(), name)).unwrap()
}

#[test]
fn the_plans_keep_the_bash_campaigns_slices() {
    let ours = list(&plan("issue-18"));
    let bash = fixture("issue-18.list");
    for (i, (a, b)) in ours.lines().zip(bash.lines()).enumerate() {
        assert_eq!(a, b, "issue-18, slice {i}");
    }
    assert_eq!(ours, bash);
    assert_eq!(plan("issue-18").slices.len(), 52);
    // The recipe's slices run by the bash lanes (0-13), unchanged; the plan grows after them.
    let ours = list(&plan("recipe"));
    let bash = fixture("recipe.list");
    let ran = 14;
    for (i, (a, b)) in ours.lines().zip(bash.lines()).take(ran).enumerate() {
        assert_eq!(a, b, "recipe, slice {i}");
    }
    assert!(plan("recipe").slices.len() > ran);
}

#[test]
fn the_plans_views_are_the_bash_campaigns() {
    // Issues 45's, 46's, 58's, 59's, 65's and 75's plans came after the translation: their views are their own
    // (below).
    let after = [
        "issue-45",
        "issue-46",
        "issue-58",
        "issue-59",
        "issue-65",
        "issue-65-v-a",
        "issue-75",
        "issue-75-tolerance",
    ];
    let views: Vec<String> = plans_in(&root().join("deploy/campaign"))
        .unwrap()
        .into_iter()
        .filter(|(name, _)| !after.contains(&name.as_str()))
        .flat_map(|(_, plan)| plan.views)
        .map(|v| format!("{} {}", v.name, v.groups.join(" ")))
        .collect();
    let bash = fixture("views.txt");
    let bash: Vec<&str> = bash.lines().collect();
    assert!(views.len() >= bash.len(), "{views:?}");
    assert_eq!(views[..bash.len()], bash[..], "the bash campaign's views");
    // The views added since the translation.
    assert_eq!(
        views[bash.len()..],
        ["v-a-v-c-recipe-view v-a-ref v-a-ref-clone-warmup-dminus v-c-ref v-c-ref-clone-warmup-dminus"]
    );
    let v_a = plan("issue-58");
    assert_eq!(v_a.views.len(), 1);
    assert_eq!(
        v_a.views[0].groups[0], "v-a-cpu-rerun",
        "issue-58: V-A's runs without the keys first, the keys beside them"
    );
    let v_b = plan("issue-59");
    assert_eq!(v_b.views.len(), 1);
    assert_eq!(
        v_b.views[0].groups[..2],
        ["v-b-frozen-eq14-hinged", "v-b-dart"],
        "issue-59: the default's runs without the keys first, the keys beside them"
    );
    for name in &after[..2] {
        let plan = plan(name);
        assert_eq!(plan.views.len(), 1, "{name}");
        assert_eq!(
            plan.views[0].groups[0], "v-b-ref-clone-warmup-dminus",
            "{name}: the recipe's runs first, the variants beside them"
        );
    }
    // Issue 65: V-C's three arms, the proposed method against the baseline that is a group of its own.
    let v_c = plan("issue-65");
    assert_eq!(v_c.views.len(), 1);
    assert_eq!(
        v_c.views[0].versus_args()[..2],
        ["--versus", "v-c-ref-ten=v-c-ref-bc-ten (baseline)"]
    );
    let v_a = plan("issue-65-v-a");
    assert_eq!(
        v_a.views[0].groups,
        ["v-a-cpu-dart", "v-a-cpu-critic-on"],
        "issue-65-v-a: the recipe's group beside its test"
    );
    // Issue 75: the default with an actor per core beside the recorded default, its count named in every slice.
    let auto = plan("issue-75");
    assert_eq!(auto.views[0].groups, ["v-b-judged", "v-b-auto"]);
    assert!(auto
        .slices
        .iter()
        .all(|s| s.text().contains("--set actors.count=2")));
    // Issue 75, later: the looser MPCC beside the default with the same two actors, both keys in every slice.
    let loose = plan("issue-75-tolerance");
    assert_eq!(loose.views[0].groups, ["v-b-auto", "v-b-tol-1e-2"]);
    assert!(loose.slices.iter().all(|s| {
        let t = s.text();
        t.contains("--set actors.count=2")
            && t.contains("--set expert.mpcc_tol_gap=1e-2")
            && t.contains("--set expert.mpcc_tol_feas=1e-3")
    }));
}

/// A slice's arguments are what bash's `eval` made of its text, and its runs are named as reproduce.sh names them.
#[test]
fn a_slices_arguments_and_runs() {
    let recipe = plan("recipe");
    let s = &recipe.slices[6];
    assert_eq!(
        s.text(),
        "--seeds 2-2 --epochs 200 --methods proposed --tag warmup-dminus --set algorithm.lambda_start=1 --set \
         algorithm.lambda_growth=1.007 --set algorithm.critic_negatives=\"d-minus\" v-b-ref"
    );
    assert_eq!(s.args()[13], "algorithm.critic_negatives=d-minus");
    let runs: Vec<String> = s.runs().iter().map(|r| r.to_string()).collect();
    assert_eq!(runs, ["v-b-ref-warmup-dminus-s2"]);
    let union = &recipe.slices[19];
    let runs: Vec<String> = union.runs().iter().map(|r| r.to_string()).collect();
    assert_eq!(
        runs,
        [
            "v-b-ref-clone-warmup-dminus-s6",
            "v-b-ref-clone-warmup-dminus-s6-baseline"
        ]
    );
    assert_eq!(union.runs()[0].seed(), 47);
}
