//! An MCAP writer that buffers each chunk's records in memory and
//! compresses the whole chunk in one call.
//!
//! Why not the `mcap` crate's writer (which hybsim still uses to read): it
//! streams every message through the chunk's CRC and compressor as about
//! seven small writes (opcode, length, four header fields, payload). A run
//! logs hundreds of thousands of small messages, and those calls cost
//! ~0.6 µs per message before any compression, as much as the simulation
//! itself on the paper models (BENCHMARKS.md, issue 19). Here a message is
//! appended to a `Vec` in place (its payload encoded directly behind its
//! header, no copy) and its index entry pushed; compression, the chunk CRC
//! and the indexes are paid once per chunk ([`CHUNK_SIZE`]).
//!
//! A full chunk goes to a thread of the writer's own, which compresses and
//! writes it (and everything else, in the caller's order) while the caller
//! fills the next: a logged run waits less for its file. The thread hands
//! emptied chunks back, so a run touches (page-faults) a few chunk buffers
//! in all; at most two chunks wait for it, so a slow disk slows the run
//! rather than filling memory. A failed write stops the thread; the calls
//! after it return the error.
//!
//! The file follows the MCAP specification (<https://mcap.dev/spec>): header;
//! a data section of schemas and channels (written when added, outside
//! chunks), metadata, attachments and chunks each followed by their message
//! indexes; `DataEnd` with the data section's CRC; a summary section
//! (schemas, channels, statistics, chunk, attachment and metadata indexes),
//! summary offsets and the footer with the summary's CRC. The output is
//! never sought, so it can be a pipe. The same calls give the same bytes.

use std::collections::BTreeMap;
use std::io::{self, Write};
use std::sync::mpsc;
use std::thread::JoinHandle;

/// Chunk compression.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Compression {
    /// Uncompressed chunks.
    None,
    /// LZ4 frames (acceleration 4): about 1.5 GB/s on a run's floats, files ~10 % larger than zstd's.
    Lz4,
    /// zstd at the given level (negative levels are zstd's fast modes).
    Zstd(i32),
}

impl Compression {
    /// The compression named `name`: `lz4`, `zstd` (level 1) or `none`.
    pub fn parse(name: &str) -> Option<Self> {
        match name {
            "lz4" => Some(Self::Lz4),
            "zstd" => Some(Self::Zstd(1)),
            "none" => Some(Self::None),
            _ => None,
        }
    }

    /// The name MCAP records carry (`""`, `lz4`, `zstd`).
    fn name(self) -> &'static str {
        match self {
            Compression::None => "",
            Compression::Lz4 => "lz4",
            Compression::Zstd(_) => "zstd",
        }
    }
}

/// Target uncompressed size of a chunk: a chunk closes once its records
/// exceed it. 256 KiB: LZ4 compresses as well as with 1 MiB (its window is
/// 64 KiB), readers decompress less to reach a message, and the buffers a
/// short run touches cost a quarter of the page faults (~0.9 ms less CPU on
/// a 30 000-message run).
pub const CHUNK_SIZE: usize = 1 << 18;

/// Bytes of a message record before its payload: opcode, content length,
/// channel id, sequence, log time, publish time.
const MESSAGE_HEAD: usize = 1 + 8 + 2 + 4 + 8 + 8;

const MAGIC: &[u8] = &[0x89, b'M', b'C', b'A', b'P', 0x30, b'\r', b'\n'];

/// Record opcodes of the MCAP specification.
pub(super) mod op {
    pub const HEADER: u8 = 0x01;
    pub const FOOTER: u8 = 0x02;
    pub const SCHEMA: u8 = 0x03;
    pub const CHANNEL: u8 = 0x04;
    pub const MESSAGE: u8 = 0x05;
    pub const CHUNK: u8 = 0x06;
    pub const MESSAGE_INDEX: u8 = 0x07;
    pub const CHUNK_INDEX: u8 = 0x08;
    pub const ATTACHMENT: u8 = 0x09;
    pub const ATTACHMENT_INDEX: u8 = 0x0A;
    pub const STATISTICS: u8 = 0x0B;
    pub const METADATA: u8 = 0x0C;
    pub const METADATA_INDEX: u8 = 0x0D;
    pub const SUMMARY_OFFSET: u8 = 0x0E;
    pub const DATA_END: u8 = 0x0F;
}

/// Little-endian field encoders of the specification's primitive types.
trait Put {
    fn u8(&mut self, v: u8);
    fn u16(&mut self, v: u16);
    fn u32(&mut self, v: u32);
    fn u64(&mut self, v: u64);
    /// `String`: u32 byte length, then UTF-8.
    fn str(&mut self, s: &str);
    /// A u32 byte length in front of what `body` appends (`Map`, `Array`, `Bytes`).
    fn prefixed32(&mut self, body: impl FnOnce(&mut Vec<u8>));
}

impl Put for Vec<u8> {
    fn u8(&mut self, v: u8) {
        self.push(v);
    }
    fn u16(&mut self, v: u16) {
        self.extend_from_slice(&v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.extend_from_slice(&v.to_le_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.extend_from_slice(&v.to_le_bytes());
    }
    fn str(&mut self, s: &str) {
        self.u32(s.len() as u32);
        self.extend_from_slice(s.as_bytes());
    }
    fn prefixed32(&mut self, body: impl FnOnce(&mut Vec<u8>)) {
        let at = self.len();
        self.u32(0);
        body(self);
        let len = (self.len() - at - 4) as u32;
        self[at..at + 4].copy_from_slice(&len.to_le_bytes());
    }
}

/// Appends a whole record: opcode, u64 content length, content.
fn record(out: &mut Vec<u8>, opcode: u8, content: impl FnOnce(&mut Vec<u8>)) {
    out.u8(opcode);
    let at = out.len();
    out.u64(0);
    content(out);
    let len = (out.len() - at - 8) as u64;
    out[at..at + 8].copy_from_slice(&len.to_le_bytes());
}

fn string_map(out: &mut Vec<u8>, map: &BTreeMap<String, String>) {
    out.prefixed32(|out| {
        for (k, v) in map {
            out.str(k);
            out.str(v);
        }
    });
}

/// The output with its position and the CRC of everything written so far.
struct Counted<W> {
    inner: W,
    position: u64,
    crc: crc32fast::Hasher,
}

impl<W: Write> Counted<W> {
    fn put(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.inner.write_all(bytes)?;
        self.position += bytes.len() as u64;
        self.crc.update(bytes);
        Ok(())
    }
}

/// The compressor of chunks, with state reused across chunks.
enum Compressor {
    None,
    Lz4,
    Zstd(Box<zstd::bulk::Compressor<'static>>),
}

impl Compressor {
    fn new(compression: Compression) -> io::Result<Self> {
        Ok(match compression {
            Compression::None => Compressor::None,
            Compression::Lz4 => Compressor::Lz4,
            Compression::Zstd(level) => {
                Compressor::Zstd(Box::new(zstd::bulk::Compressor::new(level)?))
            }
        })
    }

    /// Appends the compressed form of `data` to `out`.
    fn compress(&mut self, data: &[u8], out: &mut Vec<u8>) -> io::Result<()> {
        match self {
            Compressor::None => out.extend_from_slice(data),
            Compressor::Lz4 => lz4_frame(data, LZ4_ACCELERATION, out),
            Compressor::Zstd(z) => {
                out.reserve(zstd::zstd_safe::compress_bound(data.len()));
                z.compress_to_buffer(data, out)?;
            }
        }
        Ok(())
    }
}

/// The LZ4 frame header of every chunk: magic number; FLG = version 1,
/// independent blocks, no block or content checksum, no content size;
/// BD = 4 MiB blocks; the header checksum (second byte of the XXH32 of FLG
/// and BD). No checksums of LZ4's own: the chunk record carries the CRC of
/// its uncompressed records, the file that of its bytes.
const LZ4_HEADER: [u8; 7] = [0x04, 0x22, 0x4D, 0x18, 0x60, 0x70, 0x73];

/// Largest LZ4 block of the frame (BD above).
const LZ4_BLOCK: usize = 4 << 20;

/// LZ4's acceleration (1 is its default). A run's records are mostly
/// float bytes that LZ4 cannot shorten, and a higher acceleration makes it
/// give up on them sooner. On consensus's log (BENCHMARKS.md, issue 19,
/// sessions 14 and 16): 3 takes ~30 % fewer instructions in LZ4 than 1
/// for a file 1.8 % larger; 4 9 % fewer than 3 for 3.2 % larger, 5 14 %
/// fewer than 3 for 6.2 % larger; 6 makes the file 34 % larger.
const LZ4_ACCELERATION: i32 = 4;

/// Appends `data` as one LZ4 frame: a block per 4 MiB (one for a chunk of
/// [`CHUNK_SIZE`]), each stored as is if it does not shrink, and the end
/// mark. Written through LZ4's block function straight into `out` rather
/// than through `lz4::Encoder`, which allocates a frame context and a
/// 4 MiB buffer per chunk, copies the compressed block out of it, and
/// cannot set the acceleration. At acceleration 1 the bytes are the frame
/// that encoder writes with these settings (test
/// `lz4_frames_are_the_lz4_crates`).
fn lz4_frame(data: &[u8], acceleration: i32, out: &mut Vec<u8>) {
    out.extend_from_slice(&LZ4_HEADER);
    for block in data.chunks(LZ4_BLOCK) {
        // A block is at most 4 MiB, so its bound fits in an i32.
        let len = block.len() as i32;
        // SAFETY: LZ4_compressBound only reads its argument.
        let bound = unsafe { lz4::liblz4::LZ4_compressBound(len) };
        let size_at = out.len();
        out.reserve(4 + bound as usize);
        // SAFETY: `out` has room for `bound` bytes after the size field;
        // LZ4_compress_default reads `len` bytes of `block` and writes at
        // most `bound` bytes (it returns how many, 0 on failure), which
        // become initialized before `set_len` exposes them.
        let written = unsafe {
            let dst = out.as_mut_ptr().add(size_at + 4);
            lz4::liblz4::LZ4_compress_fast(
                block.as_ptr().cast(),
                dst.cast(),
                len,
                bound,
                acceleration,
            )
        };
        if written > 0 && written < len {
            out.extend_from_slice(&(written as u32).to_le_bytes());
            // SAFETY: the `written` bytes after the size field were just
            // written by LZ4 (see above); the size field was pushed.
            unsafe { out.set_len(size_at + 4 + written as usize) };
        } else {
            // Incompressible: stored, flagged by the size's high bit.
            out.extend_from_slice(&(block.len() as u32 | 0x8000_0000).to_le_bytes());
            out.extend_from_slice(block);
        }
    }
    out.extend_from_slice(&0u32.to_le_bytes());
}

#[derive(Clone)]
struct SchemaRecord {
    name: String,
    encoding: String,
    data: Vec<u8>,
}

#[derive(Clone)]
struct ChannelRecord {
    schema_id: u16,
    topic: String,
    encoding: String,
    metadata: BTreeMap<String, String>,
}

struct ChunkIndex {
    start_time: u64,
    end_time: u64,
    offset: u64,
    length: u64,
    message_index_offsets: BTreeMap<u16, u64>,
    message_index_length: u64,
    compressed_size: u64,
    uncompressed_size: u64,
}

struct AttachmentIndex {
    offset: u64,
    length: u64,
    log_time: u64,
    create_time: u64,
    data_size: u64,
    name: String,
    media_type: String,
}

/// What [`McapWriter::finish`] wrote.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct WrittenSummary {
    /// Messages per channel topic (channels with messages).
    pub messages: BTreeMap<String, u64>,
    /// Chunks written.
    pub chunks: u32,
}

/// Writes one MCAP file; see the module documentation.
///
/// ```
/// use std::collections::BTreeMap;
/// use hybsim::sinks::mcap_writer::{Compression, McapWriter};
/// let mut w = McapWriter::new(Vec::new(), "", "example", Compression::Lz4).unwrap();
/// let schema = w.add_schema("Point", "jsonschema", br#"{"type":"object"}"#).unwrap();
/// let channel = w.add_channel(schema, "/points", "json", &BTreeMap::new()).unwrap();
/// w.message(channel, 1, 0, |out| out.extend_from_slice(br#"{"x":1}"#)).unwrap();
/// let (bytes, summary) = w.finish().unwrap();
/// let messages: Vec<_> = mcap::MessageStream::new(&bytes).unwrap().collect();
/// assert_eq!(messages.len(), 1);
/// assert_eq!(summary.messages["/points"], 1);
/// ```
pub struct McapWriter<W: Write + Send + 'static> {
    /// The open chunk.
    chunk: OpenChunk,
    /// Where closed chunks and records outside chunks go.
    back: Backend<W>,
    schemas: Vec<SchemaRecord>,
    channels: Vec<ChannelRecord>,
    channel_counts: Vec<u64>,
    message_times: Option<(u64, u64)>,
}

/// A chunk's records, uncompressed, and its message index entries.
struct OpenChunk {
    data: Vec<u8>,
    /// Per channel: (log time, offset in `data`) of the chunk's messages.
    messages: Vec<Vec<(u64, u64)>>,
    times: Option<(u64, u64)>,
}

impl OpenChunk {
    fn new(channels: usize) -> Self {
        Self {
            data: Vec::with_capacity(CHUNK_SIZE + CHUNK_SIZE / 4),
            messages: vec![Vec::new(); channels],
            times: None,
        }
    }
}

/// What the writing thread is given, in file order.
enum Job {
    Chunk(OpenChunk),
    /// Records outside chunks (schemas, channels, metadata, attachments).
    Records(Vec<u8>, Indexed),
}

/// Which summary index a record outside chunks enters.
enum Indexed {
    No,
    Metadata(String),
    /// An attachment's index without its place in the file.
    Attachment(AttachmentIndex),
}

/// The writing thread: compresses chunks and writes everything, in the
/// order given, while the caller fills the next chunk. It returns emptied
/// chunks for reuse, so their buffers are touched (page-faulted) once.
enum Backend<W: Write> {
    Thread {
        jobs: mpsc::SyncSender<Job>,
        reused: mpsc::Receiver<OpenChunk>,
        thread: JoinHandle<io::Result<Back<W>>>,
    },
    /// After an error (or after `finish` took the thread).
    Failed,
}

/// The file and everything about what it holds: owned by the writing thread.
struct Back<W: Write> {
    out: Counted<W>,
    compressor: Compressor,
    compression: Compression,
    /// Reused buffers: compressed chunks, message indexes.
    scratch: Vec<u8>,
    indexes: Vec<u8>,
    chunk_indexes: Vec<ChunkIndex>,
    attachment_indexes: Vec<AttachmentIndex>,
    metadata_indexes: Vec<(u64, u64, String)>,
}

impl<W: Write + Send + 'static> McapWriter<W> {
    /// Writes the magic bytes and the header record, and starts the thread
    /// that writes the file.
    pub fn new(out: W, profile: &str, library: &str, compression: Compression) -> io::Result<Self> {
        let mut back = Back {
            out: Counted {
                inner: out,
                position: 0,
                crc: crc32fast::Hasher::new(),
            },
            compressor: Compressor::new(compression)?,
            compression,
            scratch: Vec::new(),
            indexes: Vec::new(),
            chunk_indexes: Vec::new(),
            attachment_indexes: Vec::new(),
            metadata_indexes: Vec::new(),
        };
        back.out.put(MAGIC)?;
        let mut header = Vec::new();
        record(&mut header, op::HEADER, |out| {
            out.str(profile);
            out.str(library);
        });
        back.out.put(&header)?;
        // Two chunks may wait: the caller then blocks instead of buffering
        // without bound when the disk is slower than the run.
        let (jobs, queue) = mpsc::sync_channel::<Job>(2);
        let (give_back, reused) = mpsc::channel();
        let thread = std::thread::Builder::new()
            .name("mcap-writer".into())
            .spawn(move || {
                for job in queue {
                    match job {
                        Job::Chunk(mut chunk) => {
                            back.write_chunk(&mut chunk)?;
                            // The caller may be gone (it failed); nothing to reuse then.
                            let _ = give_back.send(chunk);
                        }
                        Job::Records(bytes, indexed) => back.write_records(&bytes, indexed)?,
                    }
                }
                Ok(back)
            })?;
        Ok(Self {
            chunk: OpenChunk::new(0),
            back: Backend::Thread {
                jobs,
                reused,
                thread,
            },
            schemas: Vec::new(),
            channels: Vec::new(),
            channel_counts: Vec::new(),
            message_times: None,
        })
    }

    /// Hands `job` to the writing thread; if it has stopped, its error.
    fn send(&mut self, job: Job) -> io::Result<()> {
        let Backend::Thread { jobs, .. } = &self.back else {
            return Err(failed());
        };
        if jobs.send(job).is_ok() {
            return Ok(());
        }
        // The thread ended early: it met an error, which joining returns.
        self.join()?;
        Err(failed())
    }

    /// Stops the writing thread (once every job is done) and takes its state.
    fn join(&mut self) -> io::Result<Back<W>> {
        match std::mem::replace(&mut self.back, Backend::Failed) {
            Backend::Thread { jobs, thread, .. } => {
                drop(jobs);
                thread
                    .join()
                    .unwrap_or_else(|_| Err(io::Error::other("the MCAP writing thread panicked")))
            }
            Backend::Failed => Err(failed()),
        }
    }

    /// Closes the open chunk, then writes `build`'s records outside chunks.
    fn outside_chunk(
        &mut self,
        indexed: Indexed,
        build: impl FnOnce(&mut Vec<u8>),
    ) -> io::Result<()> {
        self.close_chunk()?;
        let mut bytes = Vec::new();
        build(&mut bytes);
        self.send(Job::Records(bytes, indexed))
    }

    /// Adds a schema (ids from 1); written to the data section at once.
    pub fn add_schema(&mut self, name: &str, encoding: &str, data: &[u8]) -> io::Result<u16> {
        let schema = SchemaRecord {
            name: name.into(),
            encoding: encoding.into(),
            data: data.to_vec(),
        };
        let id = u16::try_from(self.schemas.len() + 1).map_err(|_| too_many("schemas"))?;
        self.outside_chunk(Indexed::No, |out| schema_record(out, id, &schema))?;
        self.schemas.push(schema);
        Ok(id)
    }

    /// Adds a channel (ids from 0) of the schema `schema_id`.
    pub fn add_channel(
        &mut self,
        schema_id: u16,
        topic: &str,
        message_encoding: &str,
        metadata: &BTreeMap<String, String>,
    ) -> io::Result<u16> {
        if usize::from(schema_id) > self.schemas.len() {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("MCAP channel `{topic}`: unknown schema {schema_id}"),
            ));
        }
        let channel = ChannelRecord {
            schema_id,
            topic: topic.into(),
            encoding: message_encoding.into(),
            metadata: metadata.clone(),
        };
        let id = u16::try_from(self.channels.len()).map_err(|_| too_many("channels"))?;
        self.outside_chunk(Indexed::No, |out| channel_record(out, id, &channel))?;
        self.channels.push(channel);
        self.channel_counts.push(0);
        self.chunk.messages.push(Vec::new());
        Ok(id)
    }

    /// Writes a metadata record (closing the open chunk).
    pub fn write_metadata(
        &mut self,
        name: &str,
        metadata: &BTreeMap<String, String>,
    ) -> io::Result<()> {
        self.outside_chunk(Indexed::Metadata(name.into()), |out| {
            record(out, op::METADATA, |out| {
                out.str(name);
                string_map(out, metadata);
            })
        })
    }

    /// Writes an attachment record (closing the open chunk).
    pub fn attach(
        &mut self,
        log_time: u64,
        create_time: u64,
        name: &str,
        media_type: &str,
        data: &[u8],
    ) -> io::Result<()> {
        let index = AttachmentIndex {
            offset: 0,
            length: 0,
            log_time,
            create_time,
            data_size: data.len() as u64,
            name: name.into(),
            media_type: media_type.into(),
        };
        self.outside_chunk(Indexed::Attachment(index), |out| {
            record(out, op::ATTACHMENT, |out| {
                let fields = out.len();
                out.u64(log_time);
                out.u64(create_time);
                out.str(name);
                out.str(media_type);
                out.u64(data.len() as u64);
                out.extend_from_slice(data);
                // The CRC covers every field before it.
                let crc = crc32fast::hash(&out[fields..]);
                out.u32(crc);
            })
        })
    }

    /// Appends a message on `channel` to the open chunk; `payload` appends
    /// the message's bytes to the buffer it is given (in place, behind the
    /// record header). Hands the chunk to the writing thread once it
    /// exceeds [`CHUNK_SIZE`]; an error is that thread's (a failed write).
    #[inline]
    pub fn message(
        &mut self,
        channel: u16,
        sequence: u32,
        log_time: u64,
        payload: impl FnOnce(&mut Vec<u8>),
    ) -> io::Result<()> {
        let chunk = &mut self.chunk;
        let index = chunk
            .messages
            .get_mut(usize::from(channel))
            .ok_or_else(|| {
                io::Error::new(
                    io::ErrorKind::InvalidInput,
                    format!("MCAP message on unknown channel {channel}"),
                )
            })?;
        let start = chunk.data.len();
        index.push((log_time, start as u64));
        // The record's opcode, length (set below) and header fields (log
        // and publish time), appended at once: this runs per message.
        let mut head = [0u8; MESSAGE_HEAD];
        head[0] = op::MESSAGE;
        head[9..11].copy_from_slice(&channel.to_le_bytes());
        head[11..15].copy_from_slice(&sequence.to_le_bytes());
        head[15..23].copy_from_slice(&log_time.to_le_bytes());
        head[23..31].copy_from_slice(&log_time.to_le_bytes());
        chunk.data.extend_from_slice(&head);
        payload(&mut chunk.data);
        let len = (chunk.data.len() - start - 9) as u64;
        chunk.data[start + 1..start + 9].copy_from_slice(&len.to_le_bytes());
        self.channel_counts[usize::from(channel)] += 1;
        let widen = |b: Option<(u64, u64)>| match b {
            None => Some((log_time, log_time)),
            Some((s, e)) => Some((s.min(log_time), e.max(log_time))),
        };
        chunk.times = widen(chunk.times);
        self.message_times = widen(self.message_times);
        if chunk.data.len() >= CHUNK_SIZE {
            self.close_chunk()?;
        }
        Ok(())
    }

    /// Hands the open chunk (if it has records) to the writing thread and
    /// opens the next in a returned buffer.
    fn close_chunk(&mut self) -> io::Result<()> {
        if self.chunk.times.is_none() {
            return Ok(());
        }
        let channels = self.channels.len();
        let mut next = match &self.back {
            Backend::Thread { reused, .. } => reused.try_recv().ok(),
            Backend::Failed => None,
        }
        .unwrap_or_else(|| OpenChunk::new(channels));
        next.messages.resize_with(channels, Vec::new);
        let full = std::mem::replace(&mut self.chunk, next);
        self.send(Job::Chunk(full))
    }

    /// Closes the open chunk, waits for the writing thread, then writes
    /// `DataEnd`, the summary section, the summary offsets, the footer and
    /// the closing magic; returns the output and what was written.
    pub fn finish(mut self) -> io::Result<(W, WrittenSummary)> {
        self.close_chunk()?;
        let back = self.join()?;
        back.finish(&self)
    }
}

impl<W: Write + Send + 'static> Drop for McapWriter<W> {
    /// Waits for the writing thread, so that the output (a temporary file
    /// removed on drop, say) is dropped before this returns.
    fn drop(&mut self) {
        let _ = self.join();
    }
}

/// The error of a writer whose thread has already reported its failure.
fn failed() -> io::Error {
    io::Error::other("the MCAP file could not be written (an earlier write failed)")
}

impl<W: Write> Back<W> {
    /// Writes records outside chunks, entering them in their index.
    fn write_records(&mut self, bytes: &[u8], indexed: Indexed) -> io::Result<()> {
        let offset = self.out.position;
        self.out.put(bytes)?;
        let length = self.out.position - offset;
        match indexed {
            Indexed::No => {}
            Indexed::Metadata(name) => self.metadata_indexes.push((offset, length, name)),
            Indexed::Attachment(index) => self.attachment_indexes.push(AttachmentIndex {
                offset,
                length,
                ..index
            }),
        }
        Ok(())
    }

    /// Writes a chunk and its message indexes, and empties it for reuse.
    fn write_chunk(&mut self, chunk: &mut OpenChunk) -> io::Result<()> {
        let Some((start_time, end_time)) = chunk.times.take() else {
            return Ok(());
        };
        let uncompressed_crc = crc32fast::hash(&chunk.data);
        self.scratch.clear();
        self.compressor.compress(&chunk.data, &mut self.scratch)?;
        let compressed = &self.scratch;
        let mut head = Vec::with_capacity(64);
        head.u8(op::CHUNK);
        let compression = self.compression.name();
        let content = 8 + 8 + 8 + 4 + 4 + compression.len() + 8 + compressed.len();
        head.u64(content as u64);
        head.u64(start_time);
        head.u64(end_time);
        head.u64(chunk.data.len() as u64);
        head.u32(uncompressed_crc);
        head.str(compression);
        head.u64(compressed.len() as u64);
        let offset = self.out.position;
        self.out.put(&head)?;
        self.out.put(compressed)?;
        let length = self.out.position - offset;
        let compressed_size = compressed.len() as u64;

        // Message indexes, in channel order; entries by log time (stable:
        // messages of equal times keep their file order).
        let indexes = &mut self.indexes;
        indexes.clear();
        let mut message_index_offsets = BTreeMap::new();
        let index_start = self.out.position;
        for (channel, entries) in chunk.messages.iter_mut().enumerate() {
            if entries.is_empty() {
                continue;
            }
            if !entries.is_sorted_by_key(|e| e.0) {
                entries.sort_by_key(|e| e.0);
            }
            message_index_offsets.insert(channel as u16, index_start + indexes.len() as u64);
            record(indexes, op::MESSAGE_INDEX, |out| {
                out.u16(channel as u16);
                out.prefixed32(|out| {
                    for &(time, at) in entries.iter() {
                        out.u64(time);
                        out.u64(at);
                    }
                });
            });
            entries.clear();
        }
        self.out.put(&self.indexes)?;
        self.chunk_indexes.push(ChunkIndex {
            start_time,
            end_time,
            offset,
            length,
            message_index_offsets,
            message_index_length: self.indexes.len() as u64,
            compressed_size,
            uncompressed_size: chunk.data.len() as u64,
        });
        chunk.data.clear();
        Ok(())
    }

    /// `DataEnd`, the summary section (with what the caller `w` knows:
    /// schemas, channels, message counts), the summary offsets, the footer
    /// and the closing magic.
    fn finish<V: Write + Send + 'static>(
        mut self,
        w: &McapWriter<V>,
    ) -> io::Result<(W, WrittenSummary)> {
        let data_crc = self.out.crc.clone().finalize();
        let mut end = Vec::new();
        record(&mut end, op::DATA_END, |out| out.u32(data_crc));
        self.out.put(&end)?;

        // The summary's CRC starts here.
        self.out.crc = crc32fast::Hasher::new();
        let summary_start = self.out.position;
        let mut groups: Vec<(u8, u64, u64)> = Vec::new();
        let mut group = |b: &mut Self, opcode: u8, build: &dyn Fn(&Self, &mut Vec<u8>)| {
            let mut buf = Vec::new();
            build(b, &mut buf);
            if buf.is_empty() {
                return Ok(());
            }
            groups.push((opcode, b.out.position, buf.len() as u64));
            b.out.put(&buf)
        };
        group(&mut self, op::SCHEMA, &|_, out| {
            for (k, s) in w.schemas.iter().enumerate() {
                schema_record(out, k as u16 + 1, s);
            }
        })?;
        group(&mut self, op::CHANNEL, &|_, out| {
            for (k, c) in w.channels.iter().enumerate() {
                channel_record(out, k as u16, c);
            }
        })?;
        group(&mut self, op::STATISTICS, &|b, out| {
            let (start, end) = w.message_times.unwrap_or((0, 0));
            record(out, op::STATISTICS, |out| {
                out.u64(w.channel_counts.iter().sum());
                out.u16(w.schemas.len() as u16);
                out.u32(w.channels.len() as u32);
                out.u32(b.attachment_indexes.len() as u32);
                out.u32(b.metadata_indexes.len() as u32);
                out.u32(b.chunk_indexes.len() as u32);
                out.u64(start);
                out.u64(end);
                out.prefixed32(|out| {
                    for (k, &n) in w.channel_counts.iter().enumerate() {
                        out.u16(k as u16);
                        out.u64(n);
                    }
                });
            });
        })?;
        group(&mut self, op::CHUNK_INDEX, &|b, out| {
            for c in &b.chunk_indexes {
                record(out, op::CHUNK_INDEX, |out| {
                    out.u64(c.start_time);
                    out.u64(c.end_time);
                    out.u64(c.offset);
                    out.u64(c.length);
                    out.prefixed32(|out| {
                        for (&channel, &at) in &c.message_index_offsets {
                            out.u16(channel);
                            out.u64(at);
                        }
                    });
                    out.u64(c.message_index_length);
                    out.str(b.compression.name());
                    out.u64(c.compressed_size);
                    out.u64(c.uncompressed_size);
                });
            }
        })?;
        group(&mut self, op::ATTACHMENT_INDEX, &|b, out| {
            for a in &b.attachment_indexes {
                record(out, op::ATTACHMENT_INDEX, |out| {
                    out.u64(a.offset);
                    out.u64(a.length);
                    out.u64(a.log_time);
                    out.u64(a.create_time);
                    out.u64(a.data_size);
                    out.str(&a.name);
                    out.str(&a.media_type);
                });
            }
        })?;
        group(&mut self, op::METADATA_INDEX, &|b, out| {
            for (offset, length, name) in &b.metadata_indexes {
                record(out, op::METADATA_INDEX, |out| {
                    out.u64(*offset);
                    out.u64(*length);
                    out.str(name);
                });
            }
        })?;
        let summary_offset_start = self.out.position;
        let mut tail = Vec::new();
        for (opcode, start, length) in groups {
            record(&mut tail, op::SUMMARY_OFFSET, |out| {
                out.u8(opcode);
                out.u64(start);
                out.u64(length);
            });
        }
        // The footer: its CRC covers the summary through `summary_offset_start`.
        tail.u8(op::FOOTER);
        tail.u64(8 + 8 + 4);
        tail.u64(summary_start);
        tail.u64(summary_offset_start);
        self.out.crc.update(&tail);
        let summary_crc = self.out.crc.clone().finalize();
        tail.u32(summary_crc);
        tail.extend_from_slice(MAGIC);
        self.out.inner.write_all(&tail)?;
        self.out.inner.flush()?;
        let messages = w
            .channels
            .iter()
            .zip(&w.channel_counts)
            .filter(|&(_, &n)| n > 0)
            .map(|(c, &n)| (c.topic.clone(), n))
            .collect();
        let summary = WrittenSummary {
            messages,
            chunks: self.chunk_indexes.len() as u32,
        };
        Ok((self.out.inner, summary))
    }
}
fn schema_record(out: &mut Vec<u8>, id: u16, s: &SchemaRecord) {
    record(out, op::SCHEMA, |out| {
        out.u16(id);
        out.str(&s.name);
        out.str(&s.encoding);
        out.u32(s.data.len() as u32);
        out.extend_from_slice(&s.data);
    });
}

fn channel_record(out: &mut Vec<u8>, id: u16, c: &ChannelRecord) {
    record(out, op::CHANNEL, |out| {
        out.u16(id);
        out.u16(c.schema_id);
        out.str(&c.topic);
        out.str(&c.encoding);
        string_map(out, &c.metadata);
    });
}

fn too_many(what: &str) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidInput,
        format!("more MCAP {what} than the format's 16-bit ids allow"),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A file with every kind of record, several chunks and all
    /// compressions, read back by the `mcap` crate: linearly (every record
    /// and CRC checked) and through its summary and indexes.
    #[test]
    fn the_mcap_crate_reads_back_every_record() {
        for compression in [
            Compression::None,
            Compression::Lz4,
            Compression::Zstd(1),
            Compression::Zstd(-3),
        ] {
            let mut w = McapWriter::new(Vec::new(), "", "test", compression).unwrap();
            let meta = BTreeMap::from([("k".to_string(), "v".to_string())]);
            w.write_metadata("first", &meta).unwrap();
            w.attach(0, 0, "a.txt", "text/plain", b"hello").unwrap();
            let s = w.add_schema("S", "jsonschema", b"{}").unwrap();
            let a = w.add_channel(s, "/a", "json", &BTreeMap::new()).unwrap();
            let b = w.add_channel(s, "/b", "json", &meta).unwrap();
            let n = 40_000u64;
            for k in 0..n {
                let ch = if k % 3 == 0 { b } else { a };
                w.message(ch, k as u32, k / 2, |out| {
                    out.extend_from_slice(format!("{{\"k\":{k}}}").as_bytes());
                    out.extend_from_slice(&[b' '; 40]);
                })
                .unwrap();
            }
            w.write_metadata("last", &meta).unwrap();
            let (bytes, summary) = w.finish().unwrap();
            assert!(
                summary.chunks > 1,
                "{compression:?}: {} chunks",
                summary.chunks
            );
            assert_eq!(summary.messages["/a"] + summary.messages["/b"], n);

            let mut seen = 0u64;
            for (k, m) in mcap::MessageStream::new(&bytes).unwrap().enumerate() {
                let m = m.unwrap();
                assert_eq!(m.sequence as usize, k);
                assert_eq!(m.log_time, k as u64 / 2);
                assert!(m.data.starts_with(format!("{{\"k\":{k}}}").as_bytes()));
                seen += 1;
            }
            assert_eq!(seen, n);
            let read = mcap::Summary::read(&bytes).unwrap().unwrap();
            let stats = read.stats.as_ref().unwrap();
            assert_eq!(stats.message_count, n);
            assert_eq!(stats.channel_message_counts[&b], n.div_ceil(3));
            assert_eq!(read.chunk_indexes.len(), summary.chunks as usize);
            assert_eq!(read.metadata_indexes.len(), 2);
            let attachment = mcap::read::attachment(&bytes, &read.attachment_indexes[0]).unwrap();
            assert_eq!(&attachment.data[..], b"hello");
            // Every chunk's message indexes; some messages through them (each
            // seek decompresses the chunk).
            let mut indexed = 0;
            for chunk in &read.chunk_indexes {
                let index = read.read_message_indexes(&bytes, chunk).unwrap();
                for entries in index.values() {
                    for e in entries.iter().step_by(997).chain(entries.last()) {
                        let m = read.seek_message(&bytes, chunk, e).unwrap();
                        assert_eq!(m.log_time, e.log_time);
                    }
                    indexed += entries.len() as u64;
                }
            }
            assert_eq!(indexed, n);
        }
    }

    /// An output that fails after `left` bytes (a full disk).
    struct Failing {
        left: usize,
    }

    impl Write for Failing {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            if buf.len() > self.left {
                return Err(io::Error::other("disk full"));
            }
            self.left -= buf.len();
            Ok(buf.len())
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    /// A write that fails on the writing thread stops the writer: a later
    /// call returns that error (never a hang or a panic), and so does
    /// `finish`; dropping such a writer returns.
    #[test]
    fn a_failed_write_is_reported_by_the_calls_after_it() {
        for left in [0, 100, 5_000, 3 * CHUNK_SIZE / 2] {
            let started = McapWriter::new(Failing { left }, "", "test", Compression::None);
            let Ok(mut w) = started else {
                continue; // the magic bytes themselves failed
            };
            let reported = (|| {
                let s = w.add_schema("S", "jsonschema", b"{}")?;
                let c = w.add_channel(s, "/a", "json", &BTreeMap::new())?;
                for k in 0..(20 * CHUNK_SIZE / 100) as u64 {
                    w.message(c, k as u32, k, |out| out.extend_from_slice(&[b'x'; 100]))?;
                }
                Ok::<_, io::Error>(())
            })();
            match reported {
                Err(e) => assert!(
                    e.to_string().contains("disk full")
                        || e.to_string().contains("earlier write failed"),
                    "{e}"
                ),
                Ok(()) => {
                    let e = w.finish().err().expect("the file cannot be finished");
                    assert!(e.to_string().contains("disk full"), "{e}");
                }
            }
        }
        let mut w = McapWriter::new(Failing { left: 50 }, "", "test", Compression::None).unwrap();
        assert!(w.add_schema("S", "jsonschema", &[b' '; 100]).is_ok());
        drop(w);
    }

    /// At acceleration 1 the frames `lz4_frame` writes are byte for byte
    /// those of the `lz4` crate's encoder with the settings it documents;
    /// at every acceleration they decode to their input: empty, compressible, incompressible (stored) and larger than
    /// one 4 MiB block.
    #[test]
    fn lz4_frames_are_the_lz4_crates() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut noise = |n: usize| -> Vec<u8> {
            (0..n)
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    state as u8
                })
                .collect()
        };
        let floats: Vec<u8> = (0..40_000)
            .flat_map(|k| (f64::from(k) * 0.01).sin().to_le_bytes())
            .collect();
        let big: Vec<u8> = floats
            .iter()
            .copied()
            .cycle()
            .take(LZ4_BLOCK + 12_345)
            .collect();
        for data in [Vec::new(), floats, noise(70_000), big] {
            let mut ours = vec![7u8];
            lz4_frame(&data, 1, &mut ours);
            let mut encoder = lz4::EncoderBuilder::new()
                .level(1)
                .block_size(lz4::BlockSize::Max4MB)
                .block_mode(lz4::BlockMode::Independent)
                .auto_flush(true)
                .checksum(lz4::ContentChecksum::NoChecksum)
                .block_checksum(lz4::liblz4::BlockChecksum::NoBlockChecksum)
                .build(vec![7u8])
                .unwrap();
            encoder.write_all(&data).unwrap();
            let (theirs, result) = encoder.finish();
            result.unwrap();
            assert_eq!(ours, theirs, "{} bytes", data.len());
            for acceleration in [1, LZ4_ACCELERATION] {
                let mut frame = Vec::new();
                lz4_frame(&data, acceleration, &mut frame);
                let mut back = Vec::new();
                let mut decoder = lz4::Decoder::new(&frame[..]).unwrap();
                io::Read::read_to_end(&mut decoder, &mut back).unwrap();
                assert_eq!(back, data, "acceleration {acceleration}");
            }
        }
    }
}
