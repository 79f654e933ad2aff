//! The replay's steps, store after store, as rows: each labelled (D+, D?, D-, dynamics-only), cut into episodes and
//! given its policy version ([`super::lineage`]), its image encoded as PNG, counted into the statistics, and handed
//! to the data files.

use super::lineage::{same_state, Label, Versions};
use super::meta::Stats;
use super::table::{DataFiles, EpisodeRow, Row};
use super::ExportError;
use cabc_learning::replay::{ReplayError, ReplaySnapshot, Store};
use cabc_proto::messages::image_bytes;
use std::collections::BTreeMap;

/// What the rows came to.
pub struct Written {
    pub frames: u64,
    pub episodes: Vec<EpisodeRow>,
    /// Rows per label.
    pub rows: BTreeMap<&'static str, u64>,
    /// D- states matched to a D? row.
    pub minus_rows: u64,
    pub stats: Stats,
    pub data_files: u64,
}

/// A PNG of an RGB image.
fn png(rgb: &[u8], width: u16, height: u16) -> Result<Vec<u8>, ExportError> {
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, width as u32, height as u32);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let bad = |e: png::EncodingError| ExportError::Png(e.to_string());
    let mut writer = encoder.write_header().map_err(bad)?;
    writer.write_image_data(rgb).map_err(bad)?;
    writer.finish().map_err(bad)?;
    Ok(out)
}

/// Writes every step of `snapshot` into `files`: D+, then D? (its D- rows labelled so), then the dynamics-only store.
/// `image` is D+'s image size (width, height) when the run has images; `versions` the three stores' versions;
/// `replay_err` names the replay in an error.
pub fn write(
    snapshot: &ReplaySnapshot,
    image: Option<(u16, u16)>,
    versions: &[Versions; 3],
    fps: u32,
    mut files: DataFiles,
    replay_err: &dyn Fn(ReplayError) -> ExportError,
) -> Result<Written, ExportError> {
    let stores: [(&Store, Label); 3] = [
        (&snapshot.plus, Label::Plus),
        (&snapshot.uncertain, Label::Uncertain),
        (&snapshot.dynamics_only, Label::DynamicsOnly),
    ];
    let mut stats = Stats::new(image.is_some());
    let mut episodes: Vec<EpisodeRow> = Vec::new();
    // The episode being written.
    let mut open: Option<EpisodeRow> = None;
    let mut rows = BTreeMap::new();
    let (mut index, mut minus_rows) = (0i64, 0u64);
    let mut rgb = vec![0u8; image.map_or(0, |(w, h)| image_bytes(w.into(), h.into()))];
    let mut previous: Option<([f32; 6], Label)> = None;
    for (which, (store, base)) in stores.iter().enumerate() {
        for slot in 0..store.len() {
            let state = &store.states[slot];
            let label = match snapshot.minus.get(slot) {
                Some(m) if *base == Label::Uncertain && same_state(m, state) => Label::Minus,
                _ => *base,
            };
            minus_rows += u64::from(label == Label::Minus);
            let continues =
                previous.is_some_and(|(next, l)| l == label && same_state(&next, state));
            if !continues {
                if let Some(done) = open.take() {
                    episodes.push(done);
                    files.end_episode()?;
                }
            }
            let (chunk, file) = files.position();
            let episode = open.get_or_insert_with(|| EpisodeRow {
                index: episodes.len() as i64,
                length: 0,
                chunk,
                file,
                from: index,
                to: index,
                store: label.name(),
                version_min: i64::MAX,
                version_max: i64::MIN,
            });
            let version = versions[which].at(slot);
            let frame = episode.length;
            episode.length += 1;
            episode.to = index + 1;
            episode.version_min = episode.version_min.min(version);
            episode.version_max = episode.version_max.max(version);
            let png = match (which, image) {
                (0, Some((w, h))) => {
                    snapshot.plus_image(slot, &mut rgb).map_err(replay_err)?;
                    stats.add_image(&rgb);
                    Some(png(&rgb, w, h)?)
                }
                _ => None,
            };
            let floats: [&[f32]; 5] = [
                state,
                &state[..3],
                &store.expert_actions[slot],
                &store.applied_actions[slot],
                &store.next_states[slot],
            ];
            for (m, values) in stats.floats.iter_mut().zip(floats) {
                m.add(values.iter().map(|v| *v as f64));
            }
            let timestamp = frame as f32 / fps as f32;
            stats.timestamp.add([timestamp as f64]);
            let ints = [episode.index, frame, index, 0, version];
            for (m, v) in stats.ints.iter_mut().zip(ints) {
                m.add([v as f64]);
            }
            files.push(Row {
                floats,
                png,
                timestamp,
                ints,
                store: label.name(),
            })?;
            *rows.entry(label.name()).or_insert(0u64) += 1;
            previous = Some((store.next_states[slot], label));
            index += 1;
        }
    }
    episodes.extend(open.take());
    Ok(Written {
        frames: index as u64,
        episodes,
        rows,
        minus_rows,
        stats,
        data_files: files.finish()?,
    })
}
