//! Fewer points, same picture: a line drawn through many samples per pixel
//! column only ever shows the first, lowest, highest and last of them, so
//! those four (in their original order) are all that needs drawing. Spikes
//! survive; a 100 000-sample trace on 700 columns keeps at most 2 800 points.

/// Splits `points` at non-finite values: each run of finite points is drawn
/// as one polyline, and a gap in the data stays a gap in the line.
pub fn finite_runs(points: &[(f64, f64)]) -> Vec<&[(f64, f64)]> {
    points
        .split(|(x, y)| !(x.is_finite() && y.is_finite()))
        .filter(|run| !run.is_empty())
        .collect()
}

/// At most four points per column: the first, the lowest, the highest and
/// the last of each run of consecutive points that fall in one column
/// (`column` maps x to its pixel column), in their original order.
pub fn min_max_per_column(points: &[(f64, f64)], column: impl Fn(f64) -> i64) -> Vec<(f64, f64)> {
    let mut out = Vec::new();
    let mut start = 0;
    while start < points.len() {
        let col = column(points[start].0);
        let (mut lowest, mut highest) = (start, start);
        let mut end = start + 1;
        while end < points.len() && column(points[end].0) == col {
            if points[end].1 < points[lowest].1 {
                lowest = end;
            }
            if points[end].1 > points[highest].1 {
                highest = end;
            }
            end += 1;
        }
        let mut keep = [start, lowest, highest, end - 1];
        keep.sort_unstable();
        let mut last = None;
        for i in keep {
            if last != Some(i) {
                out.push(points[i]);
                last = Some(i);
            }
        }
        start = end;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_extremes_and_ends_of_a_long_trace() {
        let n = 100_000;
        let mut points: Vec<(f64, f64)> = (0..n)
            .map(|i| (i as f64, (i as f64 * 0.01).sin()))
            .collect();
        points[50_001].1 = 10.0;
        points[70_003].1 = -7.0;
        let columns = 700.0;
        let out = min_max_per_column(&points, |x| (x / n as f64 * columns) as i64);
        assert!(out.len() <= 4 * 700, "{}", out.len());
        assert!(out.contains(&(50_001.0, 10.0)));
        assert!(out.contains(&(70_003.0, -7.0)));
        assert_eq!(out.first(), points.first());
        assert_eq!(out.last(), points.last());
        // Order is kept: x never goes back.
        assert!(out.windows(2).all(|w| w[0].0 < w[1].0));
    }

    #[test]
    fn short_traces_pass_unchanged() {
        let points = [(0.0, 1.0), (1.0, 3.0), (2.0, 2.0)];
        let out = min_max_per_column(&points, |x| x as i64);
        assert_eq!(out, points);
        assert!(min_max_per_column(&[], |x| x as i64).is_empty());
    }

    #[test]
    fn non_finite_values_split_the_line() {
        let points = [
            (0.0, 1.0),
            (1.0, f64::NAN),
            (2.0, 2.0),
            (3.0, 3.0),
            (4.0, f64::INFINITY),
        ];
        let runs = finite_runs(&points);
        assert_eq!(runs.len(), 2);
        assert_eq!(runs[0], &[(0.0, 1.0)]);
        assert_eq!(runs[1], &[(2.0, 2.0), (3.0, 3.0)]);
    }
}
