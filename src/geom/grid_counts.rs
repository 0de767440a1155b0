//! How many cells of a grid are flagged over any rectangle of it, in four reads: a summed-area
//! table.

use std::ops::Range;

pub struct GridCounts {
    columns: usize,
    /// Over the cells (a row after another) with a row and column of zeros before them, how many
    /// flagged cells lie before and up to each.
    sums: Vec<u32>,
}

impl GridCounts {
    /// `flags` holds `rows` rows of `columns` cells each.
    pub fn new(flags: &[bool], rows: usize, columns: usize) -> GridCounts {
        let row = columns + 1;
        let mut sums = vec![0u32; (rows + 1) * row];
        for r in 0..rows {
            for c in 0..columns {
                sums[(r + 1) * row + c + 1] =
                    u32::from(flags[r * columns + c]) + sums[r * row + c + 1] + sums[(r + 1) * row + c]
                        - sums[r * row + c];
            }
        }
        GridCounts { columns, sums }
    }

    /// How many of the cells in rows `rows` and columns `columns` are flagged.
    pub fn count(&self, rows: Range<usize>, columns: Range<usize>) -> u32 {
        let at = |r: usize, c: usize| self.sums[r * (self.columns + 1) + c];
        at(rows.end, columns.end) + at(rows.start, columns.start)
            - at(rows.start, columns.end)
            - at(rows.end, columns.start)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_over_rectangles_are_those_of_each_cell() {
        let (rows, columns) = (7, 5);
        let flags: Vec<bool> = (0..rows * columns).map(|k| k * 7 % 3 == 0).collect();
        let counts = GridCounts::new(&flags, rows, columns);
        for r0 in 0..=rows {
            for r1 in r0..=rows {
                for c0 in 0..=columns {
                    for c1 in c0..=columns {
                        let by_cell = (r0..r1)
                            .flat_map(|r| (c0..c1).map(move |c| r * columns + c))
                            .filter(|&k| flags[k])
                            .count();
                        assert_eq!(counts.count(r0..r1, c0..c1) as usize, by_cell);
                    }
                }
            }
        }
    }
}
