//! Natural ordering of labels: runs of digits compare as numbers (`n_poly=3` before `n_poly=10`).

/// Orders labels as a reader expects: a run of digits (with an optional decimal part)
/// compares as a number, so `n_poly=3` comes before `n_poly=10` and `c = 0.5` before `c = 10`;
/// labels equal as numbers fall back to their bytes, so the order is total.
pub fn natural_cmp(a: &str, b: &str) -> std::cmp::Ordering {
    use std::cmp::Ordering;
    let (mut rest_a, mut rest_b) = (a, b);
    loop {
        let (Some(x), Some(y)) = (rest_a.chars().next(), rest_b.chars().next()) else {
            return rest_a.len().cmp(&rest_b.len()).then_with(|| a.cmp(b));
        };
        if x.is_ascii_digit() && y.is_ascii_digit() {
            let (number_a, after_a) = split_leading_number(rest_a);
            let (number_b, after_b) = split_leading_number(rest_b);
            match number_a.total_cmp(&number_b) {
                Ordering::Equal => (rest_a, rest_b) = (after_a, after_b),
                unequal => return unequal,
            }
        } else if x != y {
            return x.cmp(&y);
        } else {
            (rest_a, rest_b) = (&rest_a[x.len_utf8()..], &rest_b[y.len_utf8()..]);
        }
    }
}

/// Splits `s`, which starts with an ASCII digit, into its leading number (`12` or `1.25`) and
/// the rest.
fn split_leading_number(s: &str) -> (f64, &str) {
    let digits_end = |from: usize| {
        s[from..]
            .find(|c: char| !c.is_ascii_digit())
            .map_or(s.len(), |i| from + i)
    };
    let mut end = digits_end(0);
    if s[end..].starts_with('.') && s[end + 1..].starts_with(|c: char| c.is_ascii_digit()) {
        end = digits_end(end + 1);
    }
    // Digits with at most one decimal point always parse as f64.
    (s[..end].parse().unwrap_or(f64::NAN), &s[end..])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_sort_with_numbers_as_numbers() {
        let mut labels = vec![
            "m = c·N ln N, c = 10",
            "m = c·N ln N, c = 1.5",
            "m = c·N ln N, c = 1.25",
            "m = c·N ln N, c = 0.5",
            "x n_poly=50 y",
            "x n_poly=3 y",
            "x n_poly=10 y",
            "x n_poly=3 z",
            "x n_poly=3",
        ];
        labels.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(
            labels,
            [
                "m = c·N ln N, c = 0.5",
                "m = c·N ln N, c = 1.25",
                "m = c·N ln N, c = 1.5",
                "m = c·N ln N, c = 10",
                "x n_poly=3",
                "x n_poly=3 y",
                "x n_poly=3 z",
                "x n_poly=10 y",
                "x n_poly=50 y",
            ]
        );
        assert_eq!(natural_cmp("a 3", "a 3.0"), "a 3".cmp("a 3.0"));
        assert_eq!(natural_cmp("a 07", "a 7"), "a 07".cmp("a 7"));
    }
}
