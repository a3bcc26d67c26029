//! The stability suite against the brute-force DDA oracle (≥ 10⁶ random rays plus the
//! adversarial families). See `voxray::stability` and docs/stability.md.

use voxray::stability::{run_case, run_transform_case, standard_cases, table, transform_cases};

#[test]
fn traversal_matches_dda_oracle_on_every_case() {
    let cases = standard_cases(1_000_000);
    let total: usize = cases.iter().map(|c| c.rays.len()).sum();
    assert!(total >= 1_000_000);
    let mut reports: Vec<_> = cases.iter().map(run_case).collect();
    reports.extend(transform_cases(24_000).iter().map(run_transform_case));
    println!("{}", table(&reports));
    for r in &reports {
        assert_eq!(r.nan, 0, "{}: NaN results", r.name);
        assert_eq!(r.aborted, 0, "{}: step bound reached", r.name);
        assert!(r.max_steps <= r.step_bound, "{}", r.name);
        assert_eq!(r.mismatches, 0, "{}: {} mismatches, first: {:?}", r.name, r.mismatches, r.first_mismatch);
        assert!(r.hits > r.rays / 20, "{}: too few hits ({}) to test anything", r.name, r.hits);
        // Ties are edge/corner contacts; in the random families they must stay rare, or the
        // tie rule would be hiding bugs. (The corner and face families are made of contacts.)
        if r.name.starts_with("random") {
            assert!(r.ties * 1000 <= r.rays, "{}: {} ties of {} rays", r.name, r.ties, r.rays);
        }
        assert!(r.max_rel_dt <= 1e-5, "{}", r.name);
    }
}
