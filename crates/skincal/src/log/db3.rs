//! rosbag2's SQLite storage (`.db3`, the default of ROS 2 Humble): the `topics` table names each
//! topic's type and serialization, the `messages` table holds the CDR messages with their receive
//! time. Read with rusqlite, read-only, in receive order.

use std::collections::HashMap;
use std::path::Path;

use rusqlite::{Connection, OpenFlags};

use super::{deliver, ChannelKind, FrameNames, LogError, PassStats, Sample, Stream, Topics};

/// Streams the samples of `stream` from the rosbag2 SQLite file at `path`.
pub fn read(
    path: &Path,
    stream: Stream,
    topics: &Topics,
    visit: &mut dyn FnMut(Sample<'_>) -> Result<(), LogError>,
    progress: &mut dyn FnMut(u64),
) -> Result<PassStats, LogError> {
    let error = |e: rusqlite::Error| sql_error(path, e);
    let db = Connection::open_with_flags(
        path,
        OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
    )
    .map_err(error)?;
    let kinds = channel_kinds(&db, topics).map_err(error)?;
    let mut stats = PassStats::default();
    let mut frames = FrameNames::default();
    // Topics not read on this pass are counted (once, on a pass of the joint states), not decoded.
    let wanted: Vec<i64> = kinds
        .iter()
        .filter(|(_, k)| match k {
            ChannelKind::Joints | ChannelKind::Wrong(_) => stream.joints(),
            ChannelKind::Imu | ChannelKind::ImuArray => stream.imu(),
            ChannelKind::Other(_) => false,
        })
        .map(|(&id, _)| id)
        .collect();
    if stream.joints() {
        count_other_topics(&db, &kinds, &mut stats).map_err(error)?;
    }
    let ids = wanted
        .iter()
        .map(i64::to_string)
        .collect::<Vec<_>>()
        .join(",");
    let mut query = db
        .prepare(&format!(
            "SELECT topic_id, data FROM messages WHERE topic_id IN ({ids}) ORDER BY timestamp, id"
        ))
        .map_err(error)?;
    let mut rows = query.query([]).map_err(error)?;
    let (mut read, mut since_progress) = (0u64, 0u64);
    while let Some(row) = rows.next().map_err(error)? {
        let id: i64 = row.get(0).map_err(error)?;
        let data = row.get_ref(1).map_err(error)?;
        let Ok(body) = data.as_blob() else {
            stats.general(stream).problem(format!(
                "a message on topic id {id} whose data is not a blob"
            ));
            continue;
        };
        read += body.len() as u64;
        since_progress += body.len() as u64;
        if since_progress >= 1 << 22 {
            progress(read);
            since_progress = 0;
        }
        if let Some(kind) = kinds.get(&id) {
            deliver(kind, body, stream, topics, &mut frames, &mut stats, visit)?;
        }
    }
    progress(read);
    Ok(stats)
}

/// An SQLite error on the bag at `path`, with what it most likely means.
fn sql_error(path: &Path, e: rusqlite::Error) -> LogError {
    LogError::Db3 {
        path: path.to_path_buf(),
        reason: match &e {
            rusqlite::Error::SqliteFailure(f, _) if f.code == rusqlite::ErrorCode::NotADatabase => {
                "not an SQLite file, or a damaged one: copy the bag again".into()
            }
            rusqlite::Error::SqliteFailure(..) | rusqlite::Error::SqlInputError { .. } => format!(
                "{e} (a rosbag2 .db3 file has the tables `topics` and `messages`; was this \
                 written by rosbag2?)"
            ),
            _ => e.to_string(),
        },
    }
}

/// What each topic of the bag carries, by topic id.
fn channel_kinds(
    db: &Connection,
    topics: &Topics,
) -> Result<HashMap<i64, ChannelKind>, rusqlite::Error> {
    let mut kinds = HashMap::new();
    let mut query = db.prepare("SELECT id, name, type, serialization_format FROM topics")?;
    let mut rows = query.query([])?;
    while let Some(row) = rows.next()? {
        let id: i64 = row.get(0)?;
        let (name, kind, format): (String, String, String) =
            (row.get(1)?, row.get(2)?, row.get(3)?);
        kinds.insert(id, ChannelKind::of(&name, &kind, &format, topics));
    }
    Ok(kinds)
}

/// The messages on topics skincal does not read, counted per topic (and those on unknown topic
/// ids reported).
fn count_other_topics(
    db: &Connection,
    kinds: &HashMap<i64, ChannelKind>,
    stats: &mut PassStats,
) -> Result<(), rusqlite::Error> {
    let mut query = db.prepare("SELECT topic_id, COUNT(*) FROM messages GROUP BY topic_id")?;
    let mut rows = query.query([])?;
    while let Some(row) = rows.next()? {
        let (id, count): (i64, i64) = (row.get(0)?, row.get(1)?);
        match kinds.get(&id) {
            Some(ChannelKind::Other(topic)) => {
                *stats.joints.other_topics.entry(topic.clone()).or_default() += count as u64;
            }
            None => stats
                .joints
                .problem(format!("{count} messages on unknown topic id {id}")),
            Some(_) => {}
        }
    }
    Ok(())
}
