//! Items grouped by a dense key, each group in the items' order: a counting sort, for lists read
//! a group at a time (a cell's blocked ranges, a vertex's triangles).

/// Group `k` is `items[starts[k]..starts[k + 1]]`.
pub struct Buckets<T> {
    pub starts: Vec<usize>,
    pub items: Vec<T>,
}

impl<T: Copy + Default> Buckets<T> {
    /// Groups `pairs` of (key below `keys`, item). They are walked twice: to count, then to place,
    /// each by `for_each`, which runs nested `flat_map`s as plain nested loops where `next`
    /// does not.
    pub fn new(keys: usize, pairs: impl Iterator<Item = (usize, T)> + Clone) -> Buckets<T> {
        let mut starts = vec![0usize; keys + 1];
        pairs.clone().for_each(|(key, _)| starts[key + 1] += 1);
        for key in 0..keys {
            starts[key + 1] += starts[key];
        }
        let mut next = starts.clone();
        let mut items = vec![T::default(); starts[keys]];
        pairs.for_each(|(key, item)| {
            items[next[key]] = item;
            next[key] += 1;
        });
        Buckets { starts, items }
    }

    pub fn get(&self, key: usize) -> &[T] {
        &self.items[self.starts[key]..self.starts[key + 1]]
    }
}
