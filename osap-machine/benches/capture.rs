//! How fast the capture writer takes samples: rows per second into a
//! Parquet (snappy) and a CSV file, the writer alone and behind the
//! recorder's bounded queue (a producer thread handing rows to the writer
//! thread, as host functions do).
//!
//! `cargo bench -p osap-machine --bench capture` (prints one line per case;
//! set CAPTURE_ROWS to change the 4 000 000 rows per case).

use osap_machine::capture::{Clock, Row, SampleWriter, SeriesInfo, WriterOptions};
use std::path::Path;
use std::time::Instant;

fn series() -> Vec<SeriesInfo> {
    (0..4)
        .map(|i| SeriesInfo {
            name: format!("m{i}.analog_read(0).value"),
            clock: Clock::Source,
        })
        .collect()
}

/// Rows as a capture makes them: 4 series at 1 kHz each, time-ordered,
/// values a noisy sensor.
fn row(i: u64) -> Row {
    Row {
        time_us: 1_000_000 + (i / 4) * 1_000,
        series: (i % 4) as u16,
        value: ((i as f64) * 0.001).sin() + (i % 7) as f64 * 1e-3,
    }
}

fn direct(path: &Path, rows: u64) -> f64 {
    let start = Instant::now();
    let mut w = SampleWriter::create(path, &series(), WriterOptions::default()).unwrap();
    for i in 0..rows {
        w.push(row(i)).unwrap();
    }
    w.finish().unwrap();
    rows as f64 / start.elapsed().as_secs_f64()
}

fn queued(path: &Path, rows: u64) -> f64 {
    let start = Instant::now();
    let (tx, rx) = std::sync::mpsc::sync_channel::<Row>(1 << 17);
    let mut w = SampleWriter::create(path, &series(), WriterOptions::default()).unwrap();
    let writer = std::thread::spawn(move || {
        for r in rx {
            w.push(r).unwrap();
        }
        w.finish().unwrap();
    });
    let mut dropped = 0u64;
    for i in 0..rows {
        if tx.try_send(row(i)).is_err() {
            dropped += 1;
        }
    }
    drop(tx);
    writer.join().unwrap();
    let rate = (rows - dropped) as f64 / start.elapsed().as_secs_f64();
    if dropped > 0 {
        println!("  ({dropped} rows dropped on a full queue: the producer outran the writer)");
    }
    rate
}

fn main() {
    let rows: u64 = std::env::var("CAPTURE_ROWS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(4_000_000);
    let dir = std::env::temp_dir().join(format!("osap-capture-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for ext in ["parquet", "csv"] {
        let path = dir.join(format!("bench.{ext}"));
        let r = direct(&path, rows);
        let size = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        println!(
            "capture writer, {ext:7}: {:>10.0} rows/s ({rows} rows, {:.1} bytes/row)",
            r,
            size as f64 / rows as f64
        );
        let r = queued(&path, rows);
        println!("capture queue+writer thread, {ext:7}: {r:>10.0} rows/s");
        std::fs::remove_file(&path).unwrap();
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
