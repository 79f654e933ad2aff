//! The rows as parquet: the Arrow schema of a step, a bounded batch of rows filled one step at a time, and the data
//! files of the LeRobot v3 layout (`data/chunk-CCC/file-FFF.parquet`, a new file once one passes its size limit, at
//! an episode's end so that no episode spans two files).

use super::ExportError;
use arrow_array::builder::{ListBuilder, StringBuilder};
use arrow_array::{
    ArrayRef, BinaryArray, FixedSizeListArray, Float32Array, Int64Array, RecordBatch, StringArray,
    StructArray,
};
use arrow_schema::{DataType, Field, Fields, Schema, SchemaRef};
use parquet::arrow::ArrowWriter;
use parquet::file::properties::WriterProperties;
use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Rows a batch holds before it is written (bounded memory; with images also [`BATCH_IMAGE_BYTES`]).
pub const BATCH_ROWS: usize = 4096;
/// PNG bytes a batch holds before it is written.
pub const BATCH_IMAGE_BYTES: usize = 32 << 20;
/// Parquet row groups: at most this many rows, and about this many bytes (the writer's memory).
const ROW_GROUP_ROWS: usize = 65_536;
const ROW_GROUP_BYTES: usize = 64 << 20;
/// LeRobot's defaults: a data file is closed past this size, a chunk folder holds this many files.
pub const FILE_MB: u64 = 100;
pub const CHUNK_FILES: u64 = 1000;

/// The fixed-size float columns: (name, width).
pub const FLOAT_COLUMNS: [(&str, usize); 5] = [
    ("observation.state", 6),
    ("observation.velocity", 3),
    ("action", 2),
    ("applied_action", 2),
    ("next.observation.state", 6),
];
/// The integer columns.
pub const INT_COLUMNS: [&str; 5] = [
    "episode_index",
    "frame_index",
    "index",
    "task_index",
    "policy_version",
];
pub const IMAGE_COLUMN: &str = "observation.image";

fn float_list(width: usize) -> DataType {
    DataType::FixedSizeList(
        Arc::new(Field::new_list_field(DataType::Float32, false)),
        width as i32,
    )
}

/// Hugging Face datasets' image: a struct of the encoded bytes and a path (null here), as LeRobot stores images.
fn image_fields() -> Fields {
    Fields::from(vec![
        Field::new("bytes", DataType::Binary, true),
        Field::new("path", DataType::Utf8, true),
    ])
}

/// The schema of a row; with `images`, an image column (null where a store keeps no image).
pub fn schema(images: bool) -> SchemaRef {
    let mut fields: Vec<Field> = FLOAT_COLUMNS
        .iter()
        .map(|(name, width)| Field::new(*name, float_list(*width), false))
        .collect();
    if images {
        fields.push(Field::new(
            IMAGE_COLUMN,
            DataType::Struct(image_fields()),
            true,
        ));
    }
    fields.push(Field::new("timestamp", DataType::Float32, false));
    fields.extend(
        INT_COLUMNS
            .iter()
            .map(|n| Field::new(*n, DataType::Int64, false)),
    );
    fields.push(Field::new("store", DataType::Utf8, false));
    Arc::new(Schema::new(fields))
}

/// One row, borrowed from the replay.
pub struct Row<'a> {
    /// The float columns in [`FLOAT_COLUMNS`] order.
    pub floats: [&'a [f32]; 5],
    pub png: Option<Vec<u8>>,
    pub timestamp: f32,
    /// The integer columns in [`INT_COLUMNS`] order.
    pub ints: [i64; 5],
    pub store: &'static str,
}

/// Rows gathered column by column.
#[derive(Default)]
struct Batch {
    floats: [Vec<f32>; 5],
    images: Vec<Option<Vec<u8>>>,
    image_bytes: usize,
    timestamps: Vec<f32>,
    ints: [Vec<i64>; 5],
    stores: Vec<&'static str>,
}

impl Batch {
    fn len(&self) -> usize {
        self.timestamps.len()
    }

    fn push(&mut self, row: Row<'_>) {
        for (column, values) in self.floats.iter_mut().zip(row.floats) {
            column.extend_from_slice(values);
        }
        self.image_bytes += row.png.as_ref().map_or(0, Vec::len);
        self.images.push(row.png);
        self.timestamps.push(row.timestamp);
        for (column, v) in self.ints.iter_mut().zip(row.ints) {
            column.push(v);
        }
        self.stores.push(row.store);
    }

    fn take(&mut self, schema: &SchemaRef, images: bool) -> Result<RecordBatch, ExportError> {
        let batch = std::mem::take(self);
        let mut columns: Vec<ArrayRef> = Vec::with_capacity(schema.fields().len());
        for ((_, width), values) in FLOAT_COLUMNS.iter().zip(batch.floats) {
            let item = Arc::new(Field::new_list_field(DataType::Float32, false));
            let values = Arc::new(Float32Array::from(values));
            columns.push(Arc::new(FixedSizeListArray::try_new(
                item,
                *width as i32,
                values,
                None,
            )?));
        }
        if images {
            let nulls = batch.images.iter().map(Option::is_some).collect::<Vec<_>>();
            let bytes: BinaryArray = batch.images.iter().map(|i| i.as_deref()).collect();
            let paths = StringArray::new_null(batch.images.len());
            columns.push(Arc::new(StructArray::try_new(
                image_fields(),
                vec![Arc::new(bytes), Arc::new(paths)],
                Some(nulls.into()),
            )?));
        }
        columns.push(Arc::new(Float32Array::from(batch.timestamps)));
        for values in batch.ints {
            columns.push(Arc::new(Int64Array::from(values)));
        }
        columns.push(Arc::new(StringArray::from(batch.stores)));
        Ok(RecordBatch::try_new(schema.clone(), columns)?)
    }
}

/// The data files being written.
pub struct DataFiles {
    root: PathBuf,
    schema: SchemaRef,
    images: bool,
    writer: Option<(ArrowWriter<File>, PathBuf)>,
    /// Index of the file being written (chunk = file / CHUNK_FILES).
    file: u64,
    batch: Batch,
    max_file_bytes: u64,
}

impl DataFiles {
    /// Data files under `root` (the dataset folder), rows of [`schema`]`(images)`.
    pub fn new(root: &Path, images: bool) -> Self {
        DataFiles {
            root: root.to_path_buf(),
            schema: schema(images),
            images,
            writer: None,
            file: 0,
            batch: Batch::default(),
            max_file_bytes: FILE_MB << 20,
        }
    }

    /// (chunk, file) of the file the next row goes to.
    pub fn position(&self) -> (u64, u64) {
        (self.file / CHUNK_FILES, self.file % CHUNK_FILES)
    }

    pub fn path(root: &Path, chunk: u64, file: u64) -> PathBuf {
        root.join(format!("data/chunk-{chunk:03}/file-{file:03}.parquet"))
    }

    pub fn push(&mut self, row: Row<'_>) -> Result<(), ExportError> {
        self.batch.push(row);
        if self.batch.len() >= BATCH_ROWS || self.batch.image_bytes >= BATCH_IMAGE_BYTES {
            self.write_batch()?;
        }
        Ok(())
    }

    fn write_batch(&mut self) -> Result<(), ExportError> {
        if self.batch.len() == 0 {
            return Ok(());
        }
        if self.writer.is_none() {
            let (chunk, file) = self.position();
            let path = Self::path(&self.root, chunk, file);
            if let Some(dir) = path.parent() {
                std::fs::create_dir_all(dir).map_err(|e| ExportError::io(dir, e))?;
            }
            let out = File::create(&path).map_err(|e| ExportError::io(&path, e))?;
            let props = WriterProperties::builder()
                .set_max_row_group_row_count(Some(ROW_GROUP_ROWS))
                .set_max_row_group_bytes(Some(ROW_GROUP_BYTES))
                .build();
            self.writer = Some((
                ArrowWriter::try_new(out, self.schema.clone(), Some(props))?,
                path,
            ));
        }
        let batch = self.batch.take(&self.schema, self.images)?;
        if let Some((writer, _)) = self.writer.as_mut() {
            writer.write(&batch)?;
        }
        Ok(())
    }

    /// At an episode's end: the rows so far go out, and the file is closed once past its size limit (the next
    /// episode starts the next file).
    pub fn end_episode(&mut self) -> Result<(), ExportError> {
        let full = match &self.writer {
            Some((w, _)) => {
                (w.bytes_written() + w.in_progress_size()) as u64 >= self.max_file_bytes
            }
            None => false,
        };
        if full {
            self.write_batch()?;
            self.close_file()?;
            self.file += 1;
        }
        Ok(())
    }

    fn close_file(&mut self) -> Result<(), ExportError> {
        if let Some((writer, path)) = self.writer.take() {
            let file = writer.close()?;
            drop(file);
            File::open(&path)
                .and_then(|f| f.sync_all())
                .map_err(|e| ExportError::io(&path, e))?;
        }
        Ok(())
    }

    /// Writes what is left and closes the last file; returns the number of data files.
    pub fn finish(mut self) -> Result<u64, ExportError> {
        self.write_batch()?;
        let open = self.writer.is_some();
        self.close_file()?;
        Ok(self.file + u64::from(open))
    }
}

/// meta/episodes/chunk-000/file-000.parquet: one row per episode.
#[derive(Clone, Debug)]
pub struct EpisodeRow {
    pub index: i64,
    pub length: i64,
    pub chunk: u64,
    pub file: u64,
    pub from: i64,
    pub to: i64,
    pub store: &'static str,
    pub version_min: i64,
    pub version_max: i64,
}

/// Writes the episodes table (LeRobot v3's columns, then cabc's store and policy versions).
pub fn write_episodes(path: &Path, episodes: &[EpisodeRow], task: &str) -> Result<(), ExportError> {
    let int = |f: &dyn Fn(&EpisodeRow) -> i64| -> ArrayRef {
        Arc::new(Int64Array::from_iter_values(episodes.iter().map(f)))
    };
    let mut tasks = ListBuilder::new(StringBuilder::new());
    for _ in episodes {
        tasks.values().append_value(task);
        tasks.append(true);
    }
    let columns: Vec<(&str, ArrayRef)> = vec![
        ("episode_index", int(&|e| e.index)),
        ("tasks", Arc::new(tasks.finish())),
        ("length", int(&|e| e.length)),
        ("data/chunk_index", int(&|e| e.chunk as i64)),
        ("data/file_index", int(&|e| e.file as i64)),
        ("dataset_from_index", int(&|e| e.from)),
        ("dataset_to_index", int(&|e| e.to)),
        ("meta/episodes/chunk_index", int(&|_| 0)),
        ("meta/episodes/file_index", int(&|_| 0)),
        (
            "store",
            Arc::new(StringArray::from_iter_values(
                episodes.iter().map(|e| e.store),
            )),
        ),
        ("policy_version_min", int(&|e| e.version_min)),
        ("policy_version_max", int(&|e| e.version_max)),
    ];
    write_table(path, columns)
}

/// meta/tasks.parquet: the one task.
pub fn write_tasks(path: &Path, task: &str) -> Result<(), ExportError> {
    write_table(
        path,
        vec![
            (
                "task_index",
                Arc::new(Int64Array::from(vec![0i64])) as ArrayRef,
            ),
            ("task", Arc::new(StringArray::from(vec![task]))),
        ],
    )
}

fn write_table(path: &Path, columns: Vec<(&str, ArrayRef)>) -> Result<(), ExportError> {
    let batch = RecordBatch::try_from_iter(columns)?;
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| ExportError::io(dir, e))?;
    }
    let out = File::create(path).map_err(|e| ExportError::io(path, e))?;
    let mut writer = ArrowWriter::try_new(out, batch.schema(), None)?;
    writer.write(&batch)?;
    writer.close()?;
    Ok(())
}
