use super::*;

/// Positions quantised at 0.1 ft (as NGSIM exports them), with cell counts whose boundaries
/// fall on data points when the grid starts at the lowest position: the same points in feet
/// and in metres must fall into the same cells.
#[test]
fn cells_do_not_depend_on_the_units() {
    let c = 0.3048;
    let y: Vec<f64> = (0..=1976)
        .map(|i| ((1352.1 + i as f64 * 0.1) * 1e6).round() / 1e6)
        .collect();
    let feet: Vec<Point> = y.iter().map(|&y| [y, y]).collect();
    let metres: Vec<Point> = feet.iter().map(|p| [p[0] * c, p[1] * c]).collect();
    for n_cells in [4, 8, 12, 13] {
        let cell = 197.6 / n_cells as f64 * 1.01;
        let ft = CellGrid::new(&feet, [cell; 2]);
        let m = CellGrid::new(&metres, [cell * c; 2]);
        assert_eq!((ft.n, m.n), ([n_cells; 2], [n_cells; 2]));
        assert_eq!(ft.cells(&feet), m.cells(&metres), "{n_cells} cells");
        let used: std::collections::BTreeSet<usize> = ft.cells(&feet).into_iter().collect();
        assert_eq!(used.len(), n_cells, "every cell along the diagonal is used");
    }
}
