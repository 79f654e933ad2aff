//! The dataset's description: `meta/info.json` (LeRobot v3: features with dtype, shape and names, fps, counts,
//! paths) and `meta/stats.json` (per feature min, max, mean, std and count, accumulated row by row).

use super::table::{CHUNK_FILES, FILE_MB, FLOAT_COLUMNS, IMAGE_COLUMN, INT_COLUMNS};
use serde_json::{json, Map, Value};

/// Running min, max, sum and sum of squares per dimension (f64).
#[derive(Clone, Debug)]
pub struct Moments {
    count: u64,
    min: Vec<f64>,
    max: Vec<f64>,
    sum: Vec<f64>,
    sum_sq: Vec<f64>,
}

impl Moments {
    pub fn new(dims: usize) -> Self {
        Moments {
            count: 0,
            min: vec![f64::INFINITY; dims],
            max: vec![f64::NEG_INFINITY; dims],
            sum: vec![0.0; dims],
            sum_sq: vec![0.0; dims],
        }
    }

    pub fn add(&mut self, values: impl IntoIterator<Item = f64>) {
        self.count += 1;
        for (d, v) in values.into_iter().enumerate().take(self.sum.len()) {
            self.min[d] = self.min[d].min(v);
            self.max[d] = self.max[d].max(v);
            self.sum[d] += v;
            self.sum_sq[d] += v * v;
        }
    }

    /// Adds `count` samples of one dimension at once (an image's pixels of one channel).
    pub fn add_many(&mut self, d: usize, count: u64, min: f64, max: f64, sum: f64, sum_sq: f64) {
        self.min[d] = self.min[d].min(min);
        self.max[d] = self.max[d].max(max);
        self.sum[d] += sum;
        self.sum_sq[d] += sum_sq;
        if d == 0 {
            self.count += count;
        }
    }

    /// {min, max, mean, std, count}; `nest` wraps each value as LeRobot's image statistics are shaped, (3, 1, 1).
    pub fn to_json(&self, nest: bool) -> Value {
        let n = self.count.max(1) as f64;
        let mean: Vec<f64> = self.sum.iter().map(|s| s / n).collect();
        let std: Vec<f64> = self
            .sum_sq
            .iter()
            .zip(&mean)
            .map(|(s, m)| (s / n - m * m).max(0.0).sqrt())
            .collect();
        let finite = |v: &[f64]| -> Vec<f64> {
            v.iter()
                .map(|x| if x.is_finite() { *x } else { 0.0 })
                .collect()
        };
        let shape = |v: Vec<f64>| -> Value {
            if nest {
                json!(v.iter().map(|x| json!([[x]])).collect::<Vec<_>>())
            } else {
                json!(v)
            }
        };
        json!({
            "min": shape(finite(&self.min)),
            "max": shape(finite(&self.max)),
            "mean": shape(mean),
            "std": shape(std),
            "count": [self.count],
        })
    }
}

/// The statistics of every numeric feature.
pub struct Stats {
    pub floats: Vec<Moments>,
    pub timestamp: Moments,
    pub ints: Vec<Moments>,
    /// Per channel, pixel values scaled to [0, 1].
    pub image: Option<Moments>,
}

impl Stats {
    pub fn new(images: bool) -> Self {
        Stats {
            floats: FLOAT_COLUMNS
                .iter()
                .map(|(_, w)| Moments::new(*w))
                .collect(),
            timestamp: Moments::new(1),
            ints: INT_COLUMNS.iter().map(|_| Moments::new(1)).collect(),
            image: images.then(|| Moments::new(3)),
        }
    }

    /// Adds an RGB image's pixels (HWC).
    pub fn add_image(&mut self, rgb: &[u8]) {
        let Some(m) = self.image.as_mut() else {
            return;
        };
        for c in 0..3 {
            let (mut lo, mut hi, mut sum, mut sum_sq, mut n) = (u8::MAX, 0u8, 0u64, 0u64, 0u64);
            for &p in rgb.iter().skip(c).step_by(3) {
                lo = lo.min(p);
                hi = hi.max(p);
                sum += p as u64;
                sum_sq += (p as u64) * (p as u64);
                n += 1;
            }
            let s = 255.0;
            m.add_many(
                c,
                n,
                lo as f64 / s,
                hi as f64 / s,
                sum as f64 / s,
                sum_sq as f64 / (s * s),
            );
        }
    }

    pub fn to_json(&self) -> Value {
        let mut out = Map::new();
        for ((name, _), m) in FLOAT_COLUMNS.iter().zip(&self.floats) {
            out.insert(name.to_string(), m.to_json(false));
        }
        out.insert("timestamp".into(), self.timestamp.to_json(false));
        for (name, m) in INT_COLUMNS.iter().zip(&self.ints) {
            out.insert(name.to_string(), m.to_json(false));
        }
        if let Some(m) = &self.image {
            out.insert(IMAGE_COLUMN.into(), m.to_json(true));
        }
        Value::Object(out)
    }
}

/// The names of each float column's dimensions.
fn names(column: &str) -> Value {
    let state = ["v_long", "v_tran", "omega", "s", "x_tran", "e_psi"];
    match column {
        "observation.state" | "next.observation.state" => json!(state),
        "observation.velocity" => json!(state[..3]),
        _ => json!(["a", "delta"]),
    }
}

/// What `meta/info.json` says besides the counts.
pub struct Info<'a> {
    pub fps: u32,
    pub episodes: u64,
    pub frames: u64,
    /// (height, width) of the images, if the run has them.
    pub image: Option<(u16, u16)>,
    /// cabc's own section: the run, the stores' counts, how episodes and versions were derived.
    pub cabc: Value,
    pub task: &'a str,
}

impl Info<'_> {
    pub fn to_json(&self) -> Value {
        let mut features = Map::new();
        for (name, width) in FLOAT_COLUMNS {
            features.insert(
                name.into(),
                json!({"dtype": "float32", "shape": [width], "names": names(name)}),
            );
        }
        if let Some((h, w)) = self.image {
            features.insert(
                IMAGE_COLUMN.into(),
                json!({"dtype": "image", "shape": [h, w, 3], "names": ["height", "width", "channel"]}),
            );
        }
        features.insert(
            "timestamp".into(),
            json!({"dtype": "float32", "shape": [1], "names": null}),
        );
        for name in INT_COLUMNS {
            features.insert(
                name.into(),
                json!({"dtype": "int64", "shape": [1], "names": null}),
            );
        }
        features.insert(
            "store".into(),
            json!({"dtype": "string", "shape": [1], "names": null}),
        );
        json!({
            "codebase_version": "v3.0",
            "robot_type": "barc-dynamic-bicycle",
            "total_episodes": self.episodes,
            "total_frames": self.frames,
            "total_tasks": 1,
            "chunks_size": CHUNK_FILES,
            "data_files_size_in_mb": FILE_MB,
            "video_files_size_in_mb": 200,
            "fps": self.fps,
            "splits": {"train": format!("0:{}", self.episodes)},
            "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
            "video_path": null,
            "features": features,
            "task": self.task,
            "cabc": self.cabc,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moments_are_min_max_mean_std() {
        let mut m = Moments::new(2);
        for v in [[1.0, 10.0], [3.0, 10.0]] {
            m.add(v);
        }
        let j = m.to_json(false);
        assert_eq!(j["min"], json!([1.0, 10.0]));
        assert_eq!(j["max"], json!([3.0, 10.0]));
        assert_eq!(j["mean"], json!([2.0, 10.0]));
        assert_eq!(j["std"], json!([1.0, 0.0]));
        assert_eq!(j["count"], json!([2]));
        let mut s = Stats::new(true);
        s.add_image(&[0, 255, 51, 255, 255, 51]);
        let j = s.image.as_ref().unwrap().to_json(true);
        assert_eq!(j["mean"], json!([[[0.5]], [[1.0]], [[0.2]]]));
        assert_eq!(j["count"], json!([2]));
    }
}
