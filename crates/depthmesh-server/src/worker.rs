//! The thread that maps one session: it owns the library [`Session`],
//! decodes frames, fuses them (on rayon, never on the async executor), and
//! sends verdicts and status images back; at the end it writes the run's
//! files into `OUT/<session>/`.

use crate::jpeg::ColorType;
use crate::protocol::{pose_to_array, tagged, DepthReader, FrameMessage, Verdict, STATUS_MAGIC};
use crate::view::feed::Feed;
use depthmesh::mesh::Mesh;
use depthmesh::session::run_files::RunFiles;
use depthmesh::session::status::StatusImage;
use depthmesh::session::{FrameRecord, Session};
use depthmesh::store::checkpoints::Checkpoints;
use depthmesh::track::pyramid::half;
use depthmesh::{Frame, Intrinsics, Pose};
use serde_json::{Map, Value};
use std::collections::VecDeque;
use std::sync::{Arc, Condvar, Mutex};
use tokio::sync::{mpsc, oneshot};

/// Status images are drawn at half the sensor's resolution when it is at
/// least this wide: enough to see what is still missing, at a quarter of
/// the bytes on the link and of the ray casting on the server.
const HALVED_STATUS_WIDTH: u32 = 320;

/// Work for a session's thread.
#[derive(Debug)]
pub enum Job {
    /// Map this frame.
    Frame(FrameMessage),
    /// A frame taken at this time was dropped to keep up: the tracker
    /// predicts across it ([`Session::pass`]).
    Passed(f64),
    /// Send a copy of the current mesh.
    Mesh(oneshot::Sender<Mesh>),
    /// A viewer joined: publish the view now, not at the next frame.
    Publish,
    /// No more frames: write the run's files and stop.
    End,
}

/// What a session's thread sends back to its connection.
#[derive(Debug)]
pub enum Out {
    /// A frame's verdict.
    Verdict(Verdict),
    /// A binary message (status image, mesh).
    Binary(Vec<u8>),
    /// The session ended and its files are written.
    Finished(Map<String, Value>),
    /// A frame could not be mapped; the session ended (its files are
    /// written with what was mapped before).
    Fatal(String),
}

/// The queue between a connection and its session's thread. For a
/// recording, frames wait their turn (the client's window bounds them);
/// for a live sensor, a frame still waiting when a newer one arrives is
/// dropped, so the map follows the newest view.
#[derive(Debug, Default)]
pub struct Inbox {
    queue: Mutex<VecDeque<Job>>,
    ready: Condvar,
}

impl Inbox {
    /// Queues `job`; with `newest_only`, a frame waiting unmapped is
    /// dropped (its time stays in the queue, [`Job::Passed`]) and its
    /// index returned.
    pub fn push(&self, job: Job, newest_only: bool) -> Option<u64> {
        let mut queue = self.queue.lock().expect("inbox lock");
        let mut dropped = None;
        if newest_only && matches!(job, Job::Frame(_)) {
            for waiting in queue.iter_mut() {
                if let Job::Frame(old) = waiting {
                    let timestamp = old.timestamp;
                    dropped = Some(old.index);
                    *waiting = Job::Passed(timestamp);
                    break;
                }
            }
        }
        queue.push_back(job);
        self.ready.notify_one();
        dropped
    }

    /// Frames waiting.
    pub fn waiting_frames(&self) -> usize {
        let queue = self.queue.lock().expect("inbox lock");
        queue.iter().filter(|j| matches!(j, Job::Frame(_))).count()
    }

    fn pop(&self) -> Job {
        let mut queue = self.queue.lock().expect("inbox lock");
        loop {
            if let Some(job) = queue.pop_front() {
                return job;
            }
            queue = self.ready.wait(queue).expect("inbox lock");
        }
    }
}

/// Figures of a live session, shared with the listing.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Progress {
    /// Frames mapped (fused or lost).
    pub frames: u64,
    /// Map elements.
    pub elements: u64,
}

/// Everything a session's thread needs.
pub struct Worker {
    /// The session.
    pub session: Session,
    /// Its store's checkpoints, on a server with stores.
    pub checkpoints: Option<Checkpoints>,
    /// Its files (`OUT/<session>/`); chunk files are written as blocks are evicted.
    pub files: RunFiles,
    /// Depth outside this range (metres) is dropped, as the dataset readers do.
    pub depth_range: (f32, f32),
    /// Largest image a frame may decode to.
    pub max_pixels: u64,
    /// A status image every this many mapped frames (0: never).
    pub status_every: u32,
    /// Figures for the listing.
    pub progress: Arc<Mutex<Progress>>,
    /// What the session's viewers are sent.
    pub feed: Feed,
    /// Compressed depth received so far, bytes.
    pub bytes_in: u64,
}

impl Worker {
    /// Runs until [`Job::End`] (or the connection is gone), then writes the
    /// run's files.
    pub fn run(mut self, inbox: Arc<Inbox>, out: mpsc::UnboundedSender<Out>) {
        let k = self.session.config().intrinsics;
        let status_k = if k.width >= HALVED_STATUS_WIDTH {
            half(&k)
        } else {
            k
        };
        let mut buffers = Buffers {
            reader: DepthReader::default(),
            status: StatusImage::default(),
            jpeg: Vec::new(),
        };
        let mut mapped = 0u32;
        let mut fatal = None;
        loop {
            match inbox.pop() {
                Job::Frame(frame) => match self.map(frame, &k, &mut buffers) {
                    Ok((verdict, pose)) => {
                        mapped += 1;
                        let index = verdict.frame;
                        let _ = out.send(Out::Verdict(verdict));
                        let busy = inbox.waiting_frames() > 0;
                        self.feed.after_frame(
                            &mut self.session,
                            buffers.reader.last(),
                            self.bytes_in,
                            busy,
                        );
                        let due = self.status_every > 0 && mapped.is_multiple_of(self.status_every);
                        if let (true, Some(pose)) = (due, pose) {
                            buffers
                                .status
                                .draw(self.session.backend(), &status_k, &pose);
                            if let Some(jpeg) = encode_jpeg(&buffers.status, &mut buffers.jpeg) {
                                let _ = out.send(Out::Binary(tagged(STATUS_MAGIC, index, jpeg)));
                            }
                        }
                    }
                    Err(message) => {
                        fatal = Some(message);
                        break;
                    }
                },
                Job::Passed(timestamp) => self.session.pass(timestamp),
                Job::Mesh(reply) => {
                    let _ = reply.send(self.session.mesh().clone());
                }
                Job::Publish => {
                    self.feed.after_frame(
                        &mut self.session,
                        buffers.reader.last(),
                        self.bytes_in,
                        false,
                    );
                }
                Job::End => break,
            }
        }
        let finished = self.finish();
        let mut ended = finished.clone().unwrap_or_default();
        if let Some(m) = fatal.as_ref().or(finished.as_ref().err()) {
            ended.insert("error".into(), m.clone().into());
        }
        // The client first: its viewers' last versions need not delay it.
        let _ = out.send(match (fatal, finished) {
            (Some(m), _) => Out::Fatal(m),
            (None, Ok(summary)) => Out::Finished(summary),
            (None, Err(m)) => Out::Fatal(m),
        });
        self.feed.finish(&mut self.session, &ended);
    }

    /// Decodes and maps one frame; an error ends the session.
    fn map(
        &mut self,
        msg: FrameMessage,
        k: &Intrinsics,
        b: &mut Buffers,
    ) -> Result<(Verdict, Option<Pose>), String> {
        self.bytes_in += msg.payload.len() as u64;
        let depth = b.reader.read(&msg, k, self.depth_range, self.max_pixels)?;
        let frame = Frame {
            index: usize::try_from(msg.index).map_err(|_| "frame index too large".to_string())?,
            timestamp: msg.timestamp,
            depth: std::mem::take(depth),
            color: None,
            pose: msg.pose,
        };
        let result = self.session.push(&frame);
        b.reader.put_back(frame.depth);
        let outcome = result.map_err(|e| e.to_string())?;
        let (verdict, pose) = verdict(msg.index, outcome.record);
        self.files
            .after_frame(&mut self.session)
            .map_err(|e| format!("frame {}: {e}", msg.index))?;
        if let Some(c) = &mut self.checkpoints {
            let mapped = self.session.records().len();
            c.after_frame(&self.session, mapped, false)
                .map_err(|e| format!("frame {}: {e}", msg.index))?;
        }
        let mut p = self.progress.lock().expect("progress lock");
        p.frames += 1;
        p.elements = verdict.elements;
        Ok((verdict, pose))
    }

    /// Writes the run's files; the summary, or why they could not be written.
    fn finish(&mut self) -> Result<Map<String, Value>, String> {
        if self.session.records().is_empty() {
            return Err("the session ended before any frame was mapped".into());
        }
        let mut summary = Map::new();
        if let Some(c) = &mut self.checkpoints {
            let mapped = self.session.records().len();
            let store = c
                .finish(&self.session, mapped)
                .map_err(|e| format!("cannot checkpoint the session: {e}"))?;
            summary.insert("store".into(), store);
        }
        self.files
            .finish(&mut self.session, summary)
            .map_err(|e| format!("cannot write the session's files: {e}"))
    }
}

/// The verdict on frame `index`, and the pose it was fused with.
fn verdict(index: u64, r: &FrameRecord) -> (Verdict, Option<Pose>) {
    let verdict = Verdict {
        frame: index,
        pose: r.pose.as_ref().map(pose_to_array),
        lost: r.track.and_then(|t| t.lost).map(|l| l.to_string()),
        weak_directions: r.track.map_or(0, |t| t.weak_directions),
        dropped: false,
        ms: r.ms,
        elements: r.total_elements as u64,
    };
    (verdict, r.pose)
}

/// A session thread's reused buffers.
struct Buffers {
    reader: DepthReader,
    status: StatusImage,
    jpeg: Vec<u8>,
}

/// The status image as a greyscale JPEG in `out`.
fn encode_jpeg<'a>(image: &StatusImage, out: &'a mut Vec<u8>) -> Option<&'a [u8]> {
    crate::jpeg::encode(
        &image.pixels,
        image.width,
        image.height,
        ColorType::Luma,
        out,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use depthmesh::codec::Codec;

    fn frame(index: u64) -> Job {
        Job::Frame(FrameMessage {
            index,
            timestamp: index as f64 / 30.0,
            pose: None,
            codec: Codec::Raw,
            payload: Vec::new(),
        })
    }

    // A live sensor's frame still waiting when a newer one arrives is
    // dropped, but its time stays in its place in the queue, for the
    // tracker to predict across; a recording's frames all wait their turn.
    #[test]
    fn a_frame_dropped_for_a_newer_one_leaves_its_time_in_the_queue() {
        let inbox = Inbox::default();
        assert_eq!(inbox.push(frame(0), true), None);
        assert_eq!(inbox.push(Job::Publish, true), None);
        assert_eq!(inbox.push(frame(1), true), Some(0));
        assert_eq!(inbox.push(frame(2), true), Some(1));
        assert_eq!(inbox.waiting_frames(), 1);
        let popped: Vec<String> = (0..4)
            .map(|_| match inbox.pop() {
                Job::Frame(f) => format!("frame {}", f.index),
                Job::Passed(t) => format!("passed {:.0}", t * 30.0),
                Job::Publish => "publish".into(),
                _ => "other".into(),
            })
            .collect();
        assert_eq!(popped, ["passed 0", "publish", "passed 1", "frame 2"]);
        assert_eq!(inbox.push(frame(3), false), None);
        assert_eq!(inbox.push(frame(4), false), None);
        assert_eq!(inbox.waiting_frames(), 2);
    }
}
