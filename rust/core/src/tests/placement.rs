use super::*;
use crate::rng::{Phase, stream};

fn grid() -> Grid {
    let roi = Roi::new(0.0, 10.0, 0.0, 4.0).unwrap();
    // all the weight in the left half (bins ix 0..1 of 4)
    Grid::new(roi, 4, 2, &[1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0]).unwrap()
}

#[test]
fn draws_stay_in_weighted_bins() {
    let g = grid();
    let mut rng = stream(3, 0, Phase::Simulate, 0);
    for _ in 0..2000 {
        let p = g.draw(&mut rng);
        assert!(
            (0.0..5.0).contains(&p[0]) && (0.0..=4.0).contains(&p[1]),
            "{p:?}"
        );
    }
}

#[test]
fn placed_positions_keep_the_spacing_and_crowds_come_out_smaller() {
    let g = grid();
    let mut rng = stream(4, 0, Phase::Simulate, 0);
    let p = place(&g, 6, 1.0, &mut rng);
    assert_eq!(p.len(), 6);
    for i in 0..p.len() {
        for j in 0..i {
            assert!((p[i][0] - p[j][0]).hypot(p[i][1] - p[j][1]) >= 1.0);
        }
    }
    // a 5 x 4 area holds at most a handful of discs 3 apart: never 50
    let crowded = place(&g, 50, 3.0, &mut rng);
    assert!(
        crowded.len() < 10 && !crowded.is_empty(),
        "{}",
        crowded.len()
    );
}

#[test]
fn bad_grids_are_errors() {
    let roi = Roi::new(0.0, 1.0, 0.0, 1.0).unwrap();
    assert!(Grid::new(roi, 2, 2, &[1.0; 3]).is_err());
    assert!(Grid::new(roi, 1, 1, &[0.0]).is_err());
    assert!(Grid::new(roi, 1, 1, &[f64::NAN]).is_err());
}

#[test]
fn thinning_keeps_a_recorded_configuration_minus_its_overlaps() {
    // (0,0) and (3,0) stay; (0.5,0) is too close to the first; (3,0.9) to the second; (6,0)
    // stays; a far configuration is kept whole, in order
    let c = [[0.0, 0.0], [0.5, 0.0], [3.0, 0.0], [3.0, 0.9], [6.0, 0.0]];
    assert_eq!(thin(&c, 1.0), vec![[0.0, 0.0], [3.0, 0.0], [6.0, 0.0]]);
    assert_eq!(thin(&c, 0.4), c.to_vec());
    assert!(thin(&[], 1.0).is_empty());
}
