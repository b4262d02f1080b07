//! Parquet files as the lake writes them: reproducible bytes (fixed writer properties, no
//! wall-clock time, `created_by` naming this crate's version rather than the Parquet library's)
//! and atomic appearance (written to a hidden temporary file beside the destination, synced,
//! then renamed over it, so a crash leaves no half file under a name a reader lists).
//!
//! What it is not: the choice of names or partitions ([`super`]), or the tables' columns.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Context;
use arrow_array::RecordBatch;
use arrow_schema::SchemaRef;
use parquet::arrow::ArrowWriter;
use parquet::basic::Compression;
use parquet::file::properties::{EnabledStatistics, WriterProperties, WriterPropertiesBuilder};
use parquet::schema::types::ColumnPath;

/// Rows per Parquet row group: bounds the memory an open file holds (its row group is encoded
/// in memory until full).
pub const ROW_GROUP_ROWS: usize = 65_536;

/// The `created_by` every lake file carries.
pub fn created_by() -> String {
    format!("shimmy-monitor {}", env!("CARGO_PKG_VERSION"))
}

fn base_properties() -> WriterPropertiesBuilder {
    WriterProperties::builder()
        // PLAIN pages (no dictionary): every Parquet reader decodes them, and dictionary
        // building cost a fifth of the export's time for 8 % smaller files (docs/BENCHMARKS.md).
        .set_dictionary_enabled(false)
        .set_compression(Compression::SNAPPY)
        .set_max_row_group_row_count(Some(ROW_GROUP_ROWS))
        .set_created_by(created_by())
}

/// The writer properties of the monitor's tables: Snappy, PLAIN encoding, row groups of
/// [`ROW_GROUP_ROWS`], the library's defaults otherwise (chunk and page statistics on every
/// column), `created_by` fixed.
pub fn properties() -> WriterProperties {
    base_properties().build()
}

/// The writer properties of the decoded-signal files: as [`properties`], with min/max
/// statistics (chunk and page) on the time column `t` only. Queries select signal files by time
/// (`WHERE t BETWEEN …`), which `t`'s statistics prune; a signal's values over a row group (about
/// a minute of a busy message) span most of its range, so their statistics would prune almost
/// nothing, and computing them was a twentieth of the export's instructions.
pub fn signal_properties() -> WriterProperties {
    base_properties()
        .set_statistics_enabled(EnabledStatistics::None)
        .set_column_statistics_enabled(ColumnPath::from("t"), EnabledStatistics::Page)
        .build()
}

/// A Parquet file being written to `.<name>.tmp` beside its destination.
pub struct PartFile {
    tmp: PathBuf,
    dest: PathBuf,
    writer: Option<ArrowWriter<BufWriter<File>>>,
}

impl PartFile {
    /// Creates the destination's directory and the temporary file (truncating one a crashed
    /// run left), written with [`properties`].
    pub fn create(dest: PathBuf, schema: SchemaRef) -> anyhow::Result<PartFile> {
        Self::create_with(dest, schema, properties())
    }

    /// As [`PartFile::create`], with the given writer properties.
    pub fn create_with(
        dest: PathBuf,
        schema: SchemaRef,
        props: WriterProperties,
    ) -> anyhow::Result<PartFile> {
        let dir = dest.parent().unwrap_or(Path::new("."));
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create directory {}", dir.display()))?;
        let name = dest
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let tmp = dir.join(format!(".{name}.tmp"));
        let file =
            File::create(&tmp).with_context(|| format!("cannot create {}", tmp.display()))?;
        let writer = ArrowWriter::try_new(
            BufWriter::with_capacity(1 << 16, file),
            Arc::clone(&schema),
            Some(props),
        )
        .with_context(|| format!("parquet writer for {}", dest.display()))?;
        Ok(PartFile {
            tmp,
            dest,
            writer: Some(writer),
        })
    }

    /// Appends a batch (its schema must be the file's).
    pub fn write(&mut self, batch: &RecordBatch) -> anyhow::Result<()> {
        let w = self.writer.as_mut().expect("open until closed");
        w.write(batch)
            .with_context(|| format!("writing {}", self.tmp.display()))
    }

    /// Memory (bytes) the row group in progress holds: its encoded pages and the page being
    /// encoded.
    pub fn in_progress_bytes(&self) -> usize {
        self.writer.as_ref().map_or(0, |w| w.memory_size())
    }

    /// Ends the row group in progress (written to the file; a no-op when it is empty).
    pub fn end_row_group(&mut self) -> anyhow::Result<()> {
        let w = self.writer.as_mut().expect("open until closed");
        w.flush()
            .with_context(|| format!("writing {}", self.tmp.display()))
    }

    /// Finishes the file (footer, sync) without making it visible yet.
    pub fn close(mut self) -> anyhow::Result<Closed> {
        let w = self.writer.take().expect("open until closed");
        let buf = w
            .into_inner()
            .with_context(|| format!("finishing {}", self.tmp.display()))?;
        let file = buf
            .into_inner()
            .map_err(|e| e.into_error())
            .with_context(|| format!("writing {}", self.tmp.display()))?;
        file.sync_all()
            .with_context(|| format!("syncing {}", self.tmp.display()))?;
        Ok(Closed {
            tmp: std::mem::take(&mut self.tmp),
            dest: std::mem::take(&mut self.dest),
        })
    }
}

impl Drop for PartFile {
    /// An abandoned file (a failed log) leaves nothing behind.
    fn drop(&mut self) {
        if self.writer.is_some() {
            self.writer = None;
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

/// A finished file still under its temporary name.
#[derive(Debug)]
pub struct Closed {
    tmp: PathBuf,
    dest: PathBuf,
}

impl Closed {
    /// The name it was created for.
    pub fn dest(&self) -> &Path {
        &self.dest
    }

    /// Renames it to `dest` instead of the name it was created for (a name known only once
    /// the file was written); returns `dest`.
    pub fn commit_to(mut self, dest: PathBuf) -> anyhow::Result<PathBuf> {
        self.dest = dest;
        self.commit()
    }

    /// Renames it to its destination (replacing a file of the same name: the same input gives
    /// the same bytes); returns the destination.
    pub fn commit(mut self) -> anyhow::Result<PathBuf> {
        std::fs::rename(&self.tmp, &self.dest).with_context(|| {
            format!(
                "cannot rename {} to {}",
                self.tmp.display(),
                self.dest.display()
            )
        })?;
        self.tmp = PathBuf::new();
        Ok(std::mem::take(&mut self.dest))
    }
}

impl Drop for Closed {
    fn drop(&mut self) {
        if !self.tmp.as_os_str().is_empty() {
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

/// Writes one whole file from `batches` (the monitor's small tables).
pub fn write_file(
    dest: PathBuf,
    schema: SchemaRef,
    batches: &[RecordBatch],
) -> anyhow::Result<Closed> {
    let mut f = PartFile::create(dest, schema)?;
    for b in batches {
        f.write(b)?;
    }
    f.close()
}
