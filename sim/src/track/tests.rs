//! Unit tests of the track's private helpers.
use super::*;

#[test]
fn the_default_sim_section_is_the_l_track_with_its_pieces_searched_in_order() {
    let t = Track::of(&cabc_proto::config::SimSection::default()).unwrap();
    assert_eq!(t.pieces(), Track::l_track_barc().pieces());
    assert_eq!(t.describe(), "the L-shaped BARC track");
    assert!(t.index.is_none());
}

#[test]
fn wrap_and_unwrap() {
    assert_eq!(wrap(3.0 * PI / 2.0), -PI / 2.0);
    assert!((unwrap_diff(0.0, 2.0 * PI + 0.1) - 0.1).abs() < 1e-12);
    assert!((unwrap_diff(PI - 0.1, -PI + 0.1) - 0.2).abs() < 1e-12);
}

#[test]
fn intersection_cases() {
    assert!(segments_intersect(
        (-1.0, 0.0),
        (1.0, 0.0),
        (0.0, 1.0),
        (0.0, -1.0)
    ));
    assert!(!segments_intersect(
        (0.1, 0.0),
        (1.0, 0.0),
        (0.0, 1.0),
        (0.0, -1.0)
    ));
    // Touching endpoint counts.
    assert!(segments_intersect(
        (0.0, 0.0),
        (1.0, 0.0),
        (0.0, 1.0),
        (0.0, -1.0)
    ));
    // Collinear overlap.
    assert!(segments_intersect(
        (0.0, 0.5),
        (0.0, 2.0),
        (0.0, 1.0),
        (0.0, -1.0)
    ));
}
