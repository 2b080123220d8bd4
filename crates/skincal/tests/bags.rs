//! Logs in the formats other tools write, made from the logs skincal records: rosbag2 directories
//! and SQLite files, and ROS 1 bags written by the `rosbags` Python package.

use std::path::Path;

/// A rosbag2 directory of `files` (copied in) stored as MCAP, as `ros2 bag record -s mcap` writes.
pub fn rosbag2(dir: &Path, files: &[&Path]) {
    std::fs::create_dir_all(dir).unwrap();
    let mut listed = String::new();
    for (i, f) in files.iter().enumerate() {
        let name = format!("bag_{i}.mcap");
        std::fs::copy(f, dir.join(&name)).unwrap();
        listed.push_str(&format!("    - {name}\n"));
    }
    let metadata = format!(
        "rosbag2_bagfile_information:\n  version: 8\n  storage_identifier: mcap\n  duration:\n    nanoseconds: 1\n  relative_file_paths:\n{listed}  topics_with_message_count: []\n"
    );
    std::fs::write(dir.join("metadata.yaml"), metadata).unwrap();
}

/// A rosbag2 SQLite file (`.db3`) with the messages of the MCAP file `mcap`, in the tables
/// rosbag2 writes (`topics`, `messages`; receive time as the timestamp).
pub fn mcap_to_db3(mcap: &Path, db3: &Path) {
    let bytes = std::fs::read(mcap).unwrap();
    let db = rusqlite::Connection::open(db3).unwrap();
    db.execute_batch(
        "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL, \
         serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL); \
         CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, \
         timestamp INTEGER NOT NULL, data BLOB NOT NULL); \
         CREATE INDEX timestamp_idx ON messages (timestamp ASC); BEGIN;",
    )
    .unwrap();
    let mut ids = std::collections::HashMap::new();
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        let message = message.unwrap();
        let channel = &message.channel;
        let next = ids.len() as i64 + 1;
        let id = *ids.entry(channel.topic.clone()).or_insert_with(|| {
            let kind = channel
                .schema
                .as_ref()
                .map(|s| s.name.clone())
                .unwrap_or_default();
            db.execute(
                "INSERT INTO topics VALUES (?1, ?2, ?3, ?4, '')",
                rusqlite::params![next, channel.topic, kind, channel.message_encoding],
            )
            .unwrap();
            next
        });
        db.execute(
            "INSERT INTO messages (topic_id, timestamp, data) VALUES (?1, ?2, ?3)",
            rusqlite::params![id, message.log_time as i64, &message.data[..]],
        )
        .unwrap();
    }
    db.execute_batch("COMMIT;").unwrap();
}

/// ROS 1 bags of the CSV log `csv`, each `(path, compression)` with chunks compressed by
/// `compression` (`none`, `bz2` or `lz4`), written by the `rosbags` Python package (an independent
/// implementation of the format) in one run.
pub fn ros1_bags(csv: &Path, bags: &[(&Path, &str)]) {
    let specs: Vec<std::ffi::OsString> = bags
        .iter()
        .map(|(path, compression)| {
            let mut spec = path.as_os_str().to_owned();
            spec.push(format!(":{compression}"));
            spec
        })
        .collect();
    let mut args = vec![csv];
    args.extend(specs.iter().map(Path::new));
    crate::common::run_python("ros1_bag.py", &args);
}
