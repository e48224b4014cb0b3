use super::*;

/// A 2 x 1 grid of 10 m cells from (0, 0): eastbound 12 in the first cell, northbound 5 in the
/// second, nothing else recorded.
fn map() -> FreeSpeeds {
    let mut s = vec![f64::NAN; 2 * SECTORS];
    s[0] = 12.0; // cell (0, 0), sector 0 (east)
    s[SECTORS + 2] = 5.0; // cell (1, 0), sector 2 (north)
    FreeSpeeds::new([0.0, 0.0], 10.0, 2, 1, s).unwrap()
}

#[test]
fn free_speeds_are_looked_up_by_cell_and_heading_sector() {
    let m = map();
    assert_eq!(m.at([5.0, 5.0], [1.0, 0.0]), Some(12.0));
    // within 22.5° of east is the east sector; beyond it, the next
    assert_eq!(m.at([5.0, 5.0], [1.0, 0.4]), Some(12.0));
    assert_eq!(m.at([5.0, 5.0], [1.0, 0.42]), None);
    assert_eq!(m.at([15.0, 0.0], [0.0, 3.0]), Some(5.0));
    assert_eq!(m.at([15.0, 0.0], [1.0, 0.0]), None);
    // outside the grid: none
    for p in [[-0.1, 5.0], [20.0, 5.0], [5.0, 10.0], [f64::NAN, 0.0]] {
        assert_eq!(m.at(p, [1.0, 0.0]), None, "{p:?}");
    }
    // west wraps to sector 4 either side of ±π
    let mut s = vec![f64::NAN; SECTORS];
    s[4] = 3.0;
    let w = FreeSpeeds::new([0.0, 0.0], 1.0, 1, 1, s).unwrap();
    assert_eq!(w.at([0.5, 0.5], [-1.0, 1e-9]), Some(3.0));
    assert_eq!(w.at([0.5, 0.5], [-1.0, -1e-9]), Some(3.0));
}

#[test]
fn a_field_is_raised_to_the_free_speed_in_its_direction_and_never_slowed() {
    let m = map();
    let mut inner = |q: &[Point]| -> Result<Vec<[f64; 2]>> {
        Ok(q.iter()
            .map(|p| {
                if p[0] < 10.0 {
                    [3.0, 4.0 * (p[1] - 5.0)]
                } else {
                    [0.0, 8.0]
                }
            })
            .collect())
    };
    let mut f = AtFreeSpeed {
        inner: Box::new(&mut inner),
        speeds: &m,
    };
    let v = f.velocity(&[[5.0, 5.0], [15.0, 5.0], [5.0, 7.0]]).unwrap();
    assert_eq!(v[0], [12.0, 0.0]); // east at 3, raised to 12
    assert_eq!(v[1], [0.0, 8.0]); // north at 8, faster than its 5: kept
    assert_eq!(v[2], [3.0, 8.0]); // north-east: no free speed recorded, kept
    // the inner field's draws and support pass through (a closure: none)
    assert_eq!(f.support(&[[5.0, 5.0]]).unwrap(), None);
    assert_eq!(
        f.step_start(0, &[[5.0, 5.0]]).unwrap().offset,
        vec![[0.0; 2]]
    );
}

#[test]
fn bad_free_speed_maps_are_errors() {
    assert!(FreeSpeeds::new([0.0, 0.0], 1.0, 2, 1, vec![1.0; SECTORS]).is_err());
    assert!(FreeSpeeds::new([0.0, 0.0], 0.0, 1, 1, vec![1.0; SECTORS]).is_err());
    assert!(FreeSpeeds::new([f64::INFINITY, 0.0], 1.0, 1, 1, vec![1.0; SECTORS]).is_err());
    let mut s = vec![f64::NAN; SECTORS];
    s[1] = -1.0;
    assert!(FreeSpeeds::new([0.0, 0.0], 1.0, 1, 1, s).is_err());
}
