//! A static k-d tree for radius queries in any dimension (the neighbour search of eq. (19)).
//!
//! Built once per labelling pass over D+: points are copied into tree order (contiguous, so a leaf is one slice),
//! split at the median of the widest dimension, leaves of up to [`LEAF`] points.

/// Points per leaf.
const LEAF: usize = 16;

#[derive(Clone, Debug)]
enum Node {
    Leaf {
        start: usize,
        end: usize,
    },
    Split {
        dim: usize,
        value: f64,
        left: usize,
        right: usize,
    },
}

#[derive(Clone, Debug)]
pub struct KdTree {
    dim: usize,
    /// Points in tree order, row-major.
    points: Vec<f64>,
    /// Tree position -> index in the caller's array.
    index: Vec<usize>,
    nodes: Vec<Node>,
}

impl KdTree {
    /// `points`: n rows of `dim` values, row-major.
    pub fn new(points: &[f64], dim: usize) -> Self {
        assert!(dim > 0 && points.len() % dim == 0);
        let n = points.len() / dim;
        let mut index: Vec<usize> = (0..n).collect();
        let mut nodes = Vec::with_capacity(2 * n / LEAF + 1);
        if n > 0 {
            build(points, dim, &mut index, 0, &mut nodes);
        }
        let mut ordered = Vec::with_capacity(points.len());
        for &i in &index {
            ordered.extend_from_slice(&points[i * dim..(i + 1) * dim]);
        }
        KdTree {
            dim,
            points: ordered,
            index,
            nodes,
        }
    }

    pub fn dim(&self) -> usize {
        self.dim
    }

    pub fn len(&self) -> usize {
        self.index.len()
    }

    pub fn is_empty(&self) -> bool {
        self.index.is_empty()
    }

    /// The point at tree position `pos`.
    pub fn point(&self, pos: usize) -> &[f64] {
        &self.points[pos * self.dim..(pos + 1) * self.dim]
    }

    /// The caller's index of the point at tree position `pos`.
    pub fn original_index(&self, pos: usize) -> usize {
        self.index[pos]
    }

    /// Tree positions of every point within Euclidean distance `radius` of `q` (closed ball), appended to `out`.
    pub fn within(&self, q: &[f64], radius: f64, out: &mut Vec<usize>) {
        if self.nodes.is_empty() {
            return;
        }
        let r2 = radius * radius;
        let mut stack = [0usize; 128];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            match self.nodes[stack[top]] {
                Node::Leaf { start, end } => {
                    for pos in start..end {
                        let p = self.point(pos);
                        let mut d2 = 0.0;
                        for k in 0..self.dim {
                            let t = p[k] - q[k];
                            d2 += t * t;
                        }
                        if d2 <= r2 {
                            out.push(pos);
                        }
                    }
                }
                Node::Split {
                    dim,
                    value,
                    left,
                    right,
                } => {
                    let delta = q[dim] - value;
                    if delta <= radius {
                        stack[top] = left;
                        top += 1;
                    }
                    if delta >= -radius {
                        stack[top] = right;
                        top += 1;
                    }
                }
            }
        }
    }
}

/// Builds the subtree over `index[..]` (positions `offset..offset + index.len()`), returns its node id.
fn build(
    points: &[f64],
    dim: usize,
    index: &mut [usize],
    offset: usize,
    nodes: &mut Vec<Node>,
) -> usize {
    let id = nodes.len();
    if index.len() <= LEAF {
        nodes.push(Node::Leaf {
            start: offset,
            end: offset + index.len(),
        });
        return id;
    }
    // Widest dimension.
    let mut best = (0, -1.0);
    for k in 0..dim {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for &i in index.iter() {
            let v = points[i * dim + k];
            lo = lo.min(v);
            hi = hi.max(v);
        }
        if hi - lo > best.1 {
            best = (k, hi - lo);
        }
    }
    let split_dim = best.0;
    let mid = index.len() / 2;
    index.select_nth_unstable_by(mid, |&a, &b| {
        points[a * dim + split_dim].total_cmp(&points[b * dim + split_dim])
    });
    let value = points[index[mid] * dim + split_dim];
    nodes.push(Node::Leaf { start: 0, end: 0 }); // placeholder
    let (lo, hi) = index.split_at_mut(mid);
    // Left holds values <= value, right values >= value (select_nth guarantees it).
    let left = build(points, dim, lo, offset, nodes);
    let right = build(points, dim, hi, offset + mid, nodes);
    nodes[id] = Node::Split {
        dim: split_dim,
        value,
        left,
        right,
    };
    id
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn radius_query_matches_a_scan() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        for dim in [1, 2, 6] {
            let n = 2000;
            let pts: Vec<f64> = (0..n * dim).map(|_| rng.gen_range(-1.0..1.0)).collect();
            let tree = KdTree::new(&pts, dim);
            for _ in 0..50 {
                let q: Vec<f64> = (0..dim).map(|_| rng.gen_range(-1.2..1.2)).collect();
                let r = rng.gen_range(0.05..0.8);
                let mut got = Vec::new();
                tree.within(&q, r, &mut got);
                let mut got: Vec<usize> = got.into_iter().map(|p| tree.original_index(p)).collect();
                got.sort_unstable();
                let want: Vec<usize> = (0..n)
                    .filter(|&i| {
                        (0..dim)
                            .map(|k| (pts[i * dim + k] - q[k]).powi(2))
                            .sum::<f64>()
                            <= r * r
                    })
                    .collect();
                assert_eq!(got, want);
            }
        }
    }
}
