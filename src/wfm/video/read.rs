//! Reading H.264 mp4 files: the ISO-BMFF boxes checked before the `mp4` crate sees them, the
//! video track's samples, and OpenH264 decoding to RGB frames (BT.601 limited range).

use crate::error::{Error, Result};
use image::RgbImage;
use openh264::decoder::{DecodeOptions, Decoder, DecoderConfig, Flush};
use openh264::formats::YUVSource;
use openh264::OpenH264API;
use std::io::Cursor;
use std::path::Path;

/// What a probe of an mp4 file found.
#[derive(Clone, Debug, PartialEq)]
pub struct VideoInfo {
    /// Sample-entry four-character code of the video track, e.g. "avc1" or "mp4v".
    pub codec: String,
    pub width: u32,
    pub height: u32,
    pub frame_count: u32,
    pub fps: f64,
}

/// Human name of a sample-entry code, for error messages.
pub(super) fn codec_name(fourcc: &str) -> &'static str {
    match fourcc {
        "avc1" | "avc3" => "H.264",
        "mp4v" => "MPEG-4 Part 2",
        "hvc1" | "hev1" => "H.265/HEVC",
        "vp09" => "VP9",
        "av01" => "AV1",
        "mjpa" | "mjpb" | "jpeg" => "Motion JPEG",
        _ => "unknown",
    }
}

/// I420 planes (with strides) -> RGB, BT.601 limited range, nearest chroma.
pub(super) fn i420_to_rgb(yuv: &impl YUVSource) -> RgbImage {
    let (w, h) = yuv.dimensions();
    let (sy, su, sv) = yuv.strides();
    let (yp, up, vp) = (yuv.y(), yuv.u(), yuv.v());
    let mut out = RgbImage::new(w as u32, h as u32);
    let buf: &mut [u8] = out.as_mut();
    for row in 0..h {
        for col in 0..w {
            let y = 1.164_383 * (yp[row * sy + col] as f32 - 16.0);
            let u = up[(row / 2) * su + col / 2] as f32 - 128.0;
            let v = vp[(row / 2) * sv + col / 2] as f32 - 128.0;
            let o = 3 * (row * w + col);
            buf[o] = (y + 1.596_027 * v + 0.5).clamp(0.0, 255.0) as u8;
            buf[o + 1] = (y - 0.391_762 * u - 0.812_968 * v + 0.5).clamp(0.0, 255.0) as u8;
            buf[o + 2] = (y + 2.017_232 * u + 0.5).clamp(0.0, 255.0) as u8;
        }
    }
    out
}

/// NAL units (without start codes) of an Annex B stream.
pub(super) fn split_annexb(s: &[u8]) -> Vec<&[u8]> {
    let mut starts = Vec::new();
    let mut i = 0;
    while i + 3 <= s.len() {
        if s[i] == 0 && s[i + 1] == 0 && s[i + 2] == 1 {
            starts.push(i + 3);
            i += 3;
        } else {
            i += 1;
        }
    }
    let mut out = Vec::with_capacity(starts.len());
    for (k, &st) in starts.iter().enumerate() {
        let mut end = starts.get(k + 1).map(|&n| n - 3).unwrap_or(s.len());
        // A 4-byte start code leaves one extra zero before the next unit; trailing zeros are
        // never part of a NAL unit.
        while end > st && s[end - 1] == 0 {
            end -= 1;
        }
        if end > st {
            out.push(&s[st..end]);
        }
    }
    out
}

// ------------------------------------------------------------------------------------------
// Reading
// ------------------------------------------------------------------------------------------

/// One ISO-BMFF box: its type, its payload, and the payload's offset in the file.
struct Mp4Box<'a> {
    kind: [u8; 4],
    body: &'a [u8],
    at: usize,
}

/// Boxes that hold only boxes (walked by [`check_boxes`] and the sample-entry probe).
const CONTAINERS: [&[u8; 4]; 11] = [
    b"moov", b"trak", b"mdia", b"minf", b"stbl", b"dinf", b"edts", b"udta", b"mvex", b"moof",
    b"traf",
];

/// The boxes of `s` (at file offset `at`), or the first malformed box: a size of 0 (only
/// allowed for the last top-level box, meaning "to the end of the file"), smaller than
/// its header, or past its parent's end.
fn boxes_at(s: &[u8], at: usize, top: bool) -> std::result::Result<Vec<Mp4Box<'_>>, String> {
    let mut out = Vec::new();
    let mut pos = 0usize;
    while pos < s.len() {
        let r = &s[pos..];
        if r.len() < 8 {
            if top {
                break; // the demuxer stops at the end of the file
            }
            // Inside a box the demuxer would read the next box's bytes as this header
            // (and loop forever when that reads as size 0).
            return Err(format!(
                "{} trailing bytes at byte {} (not a box header)",
                r.len(),
                at + pos
            ));
        }
        let size32 = u32::from_be_bytes([r[0], r[1], r[2], r[3]]) as u64;
        let kind = [r[4], r[5], r[6], r[7]];
        let name = String::from_utf8_lossy(&kind).into_owned();
        let (size, header) = match size32 {
            0 if top => (r.len() as u64, 8),
            0 => return Err(format!("box {name:?} at byte {} has size 0", at + pos)),
            1 if r.len() >= 16 => (
                u64::from_be_bytes([r[8], r[9], r[10], r[11], r[12], r[13], r[14], r[15]]),
                16,
            ),
            1 => return Err(format!("box {name:?} at byte {}: truncated size", at + pos)),
            _ => (size32, 8),
        };
        if size < header as u64 || size > r.len() as u64 {
            return Err(format!(
                "box {name:?} at byte {} has size {size} ({} bytes available)",
                at + pos,
                r.len()
            ));
        }
        out.push(Mp4Box {
            kind,
            body: &r[header..size as usize],
            at: at + pos + header,
        });
        pos += size as usize;
    }
    Ok(out)
}

/// Check the box tree the demuxer will walk: every box inside a container must be well
/// sized (the `mp4` crate loops forever on a nested box of size 0), containers nest at most
/// 16 deep, and the sample tables must fit their boxes. Returns the mvhd-free error text.
fn check_boxes(bytes: &[u8]) -> std::result::Result<(), String> {
    /// Where the child boxes of a box of this kind start in its payload, if it has any
    /// that the demuxer walks.
    fn children_at(kind: &[u8; 4], body: &[u8], parent: &[u8; 4]) -> Option<usize> {
        if CONTAINERS.contains(&kind) || parent == b"ilst" || kind == b"ilst" {
            return Some(0);
        }
        match kind {
            // Full box (version/flags); some files omit them and start with hdlr.
            b"meta" => Some(if body.get(4..8) == Some(b"hdlr") {
                0
            } else {
                4
            }),
            // Full box + entry count, then sample entries / data references (the demuxer
            // loops `entry_count` times over the latter without checking that a box of
            // size 0 moves it forward: libFuzzer's mp4 timeout).
            b"stsd" | b"dref" => Some(8),
            // Visual sample entries: 78 bytes of fields, then boxes (avcC, ...).
            b"avc1" | b"avc3" | b"hvc1" | b"hev1" | b"mp4v" | b"vp09" | b"av01" => Some(78),
            // Audio sample entries: 28 bytes of fields, then boxes (esds, ...).
            b"mp4a" => Some(28),
            _ => None,
        }
    }
    fn walk(
        s: &[u8],
        at: usize,
        depth: usize,
        parent: &[u8; 4],
        file_len: usize,
    ) -> std::result::Result<(), String> {
        if depth > 16 {
            return Err(format!("boxes nested more than 16 deep at byte {at}"));
        }
        for b in boxes_at(s, at, depth == 0)? {
            if let Some(off) = children_at(&b.kind, b.body, parent) {
                if off > b.body.len() {
                    let name = String::from_utf8_lossy(&b.kind).into_owned();
                    return Err(format!(
                        "box {name:?} at byte {} is {} bytes, shorter than its {off}-byte header",
                        b.at,
                        b.body.len()
                    ));
                }
                walk(&b.body[off..], b.at + off, depth + 1, &b.kind, file_len)?;
            } else if &b.kind == b"emsg" && depth == 0 && !emsg_fits(b.body) {
                // The demuxer reads top-level `emsg` boxes and subtracts the size of their
                // fields from the box size unchecked (libFuzzer's mp4 crash of session 12).
                return Err(format!(
                    "emsg at byte {} ({} bytes) is shorter than its fields",
                    b.at,
                    b.body.len()
                ));
            } else if &b.kind == b"stsz" && b.body.len() >= 12 {
                // version/flags (4), sample_size (4), sample_count (4), then sizes if 0.
                let size = u32::from_be_bytes([b.body[4], b.body[5], b.body[6], b.body[7]]);
                let count = u32::from_be_bytes([b.body[8], b.body[9], b.body[10], b.body[11]]);
                // Each sample takes at least one byte of the file (and `size` if constant).
                let each = (size as u64).max(1);
                if (count as u64).saturating_mul(each) > file_len as u64 {
                    return Err(format!(
                        "stsz at byte {} declares {count} samples of {each} bytes, more than \
                         the {file_len}-byte file holds",
                        b.at,
                    ));
                }
            }
        }
        Ok(())
    }
    walk(bytes, 0, 0, b"\0\0\0\0", bytes.len())
}

/// Whether an `emsg` payload holds its version's fields: version and flags, then (version 0)
/// two NUL-terminated strings and four 32-bit fields, or (version 1) 20 bytes of fields and
/// two NUL-terminated strings. The `mp4` crate reads the strings up to their NUL, past the
/// box's end if need be, and computes the message size as the box size minus the fields
/// (an overflow when they do not fit). Other versions are the crate's own error.
fn emsg_fits(body: &[u8]) -> bool {
    fn two_strings(s: &[u8]) -> Option<usize> {
        let a = s.iter().position(|&c| c == 0)? + 1;
        let b = s[a..].iter().position(|&c| c == 0)? + 1;
        Some(a + b)
    }
    let Some(rest) = body.get(4..) else {
        return false;
    };
    match body[0] {
        0 => two_strings(rest).is_some_and(|n| rest.len() >= n + 16),
        1 => rest.get(20..).and_then(two_strings).is_some(),
        _ => true,
    }
}

/// The sample-entry codes of the video ('vide' handler) tracks with their file offsets,
/// found by walking the boxes ourselves so the error for an unsupported codec can name it.
fn video_sample_entries(bytes: &[u8]) -> Vec<(String, usize)> {
    fn boxes(s: &[u8], at: usize) -> Vec<Mp4Box<'_>> {
        boxes_at(s, at, false).unwrap_or_default()
    }
    fn child<'a>(s: &'a [u8], at: usize, kind: &[u8; 4]) -> Option<Mp4Box<'a>> {
        boxes(s, at).into_iter().find(|b| &b.kind == kind)
    }
    let mut codecs = Vec::new();
    let Some(moov) = boxes_at(bytes, 0, true)
        .unwrap_or_default()
        .into_iter()
        .find(|b| &b.kind == b"moov")
    else {
        return codecs;
    };
    for trak in boxes(moov.body, moov.at) {
        if &trak.kind != b"trak" {
            continue;
        }
        let Some(mdia) = child(trak.body, trak.at, b"mdia") else {
            continue;
        };
        // hdlr: version/flags (4), pre_defined (4), handler_type (4).
        let is_video = child(mdia.body, mdia.at, b"hdlr")
            .map(|h| h.body.len() >= 12 && &h.body[8..12] == b"vide")
            .unwrap_or(false);
        let stsd = child(mdia.body, mdia.at, b"minf")
            .and_then(|m| child(m.body, m.at, b"stbl"))
            .and_then(|s| child(s.body, s.at, b"stsd"));
        // stsd: version/flags (4), entry_count (4), then sample entries as boxes.
        if let (true, Some(stsd)) = (is_video, stsd) {
            if stsd.body.len() >= 16 {
                codecs.push((
                    String::from_utf8_lossy(&stsd.body[12..16]).into_owned(),
                    stsd.at + 12,
                ));
            }
        }
    }
    codecs
}

/// Probe an mp4: codec, size, frame count and frame rate of its first video track.
pub fn probe_mp4(path: &Path) -> Result<VideoInfo> {
    let bytes = crate::io::limits::read_file(path)?;
    let codecs = video_sample_entries(&bytes);
    let codec = codecs.first().map(|c| c.0.clone()).ok_or_else(|| {
        Error::format(
            path,
            "moov/trak (video)",
            "an mp4 with a video track",
            "no video track",
        )
    })?;
    if codec != "avc1" && codec != "avc3" {
        return Ok(VideoInfo {
            codec,
            width: 0,
            height: 0,
            frame_count: 0,
            fps: 0.0,
        });
    }
    let bytes = as_avc1(bytes);
    let reader = open_reader(path, &bytes)?;
    let track = h264_track(path, &reader)?;
    let frame_count = check_sample_table(track, bytes.len() as u64)
        .map_err(|e| Error::format(path, "mp4 sample table", "a consistent sample table", e))?;
    // The crate's `frame_rate` divides by the timescale unchecked (0 in a damaged mdhd)
    // and multiplies the duration into overflow: the same value (frames per whole
    // millisecond of duration, truncated), computed checked.
    let mdhd = &track.trak.mdia.mdhd;
    let dur_msec = (mdhd.duration as u128 * 1000)
        .checked_div(mdhd.timescale as u128)
        .unwrap_or(0);
    let fps = (frame_count as u128 * 1000)
        .checked_div(dur_msec)
        .map_or(0.0, |f| f as f64);
    Ok(VideoInfo {
        codec,
        width: track.width() as u32,
        height: track.height() as u32,
        frame_count,
        fps,
    })
}

/// `avc3` differs from `avc1` only in allowing parameter sets inside the samples (the
/// decoder is given every NAL unit either way), but the `mp4` crate parses only `avc1`
/// entries: rename them in a copy.
fn as_avc1(mut bytes: Vec<u8>) -> Vec<u8> {
    for (c, at) in video_sample_entries(&bytes) {
        if c == "avc3" {
            bytes[at..at + 4].copy_from_slice(b"avc1");
        }
    }
    bytes
}

fn open_reader<'a>(path: &Path, bytes: &'a [u8]) -> Result<mp4::Mp4Reader<Cursor<&'a [u8]>>> {
    let bad =
        |found: String| Error::format(path, "mp4 boxes", "a well-formed ISO-BMFF file", found);
    check_boxes(bytes).map_err(bad)?;
    let len = bytes.len() as u64;
    // The demuxer is third-party code on untrusted input: a panic becomes an error.
    std::panic::catch_unwind(|| mp4::Mp4Reader::read_header(Cursor::new(bytes), len))
        .map_err(|_| bad("a file the demuxer could not parse".into()))?
        .map_err(|e| bad(e.to_string()))
}

/// Check the sample tables of `track` before the demuxer follows them: the `mp4` crate
/// divides by `samples_per_chunk`, subtracts 1 from chunk numbers, unwraps the `stts` entry
/// of each sample, adds chunk offsets to sample offsets and allocates each sample's declared
/// size, all unchecked. A table that would make it panic or allocate more than the file
/// holds is refused here (the `catch_unwind` around the demuxer stays as a second line).
/// Returns the sample count.
fn check_sample_table(track: &mp4::Mp4Track, file_len: u64) -> std::result::Result<u32, String> {
    let stbl = &track.trak.mdia.minf.stbl;
    let too_big =
        |what: &str, v: u64| format!("{what} {v} is more than the {file_len}-byte file holds");
    if !track.trafs.is_empty() {
        // Fragmented file: the crate sums the trun counts with `expect`, divides the count
        // by the number of fragments and multiplies sample numbers by the default duration.
        let mut count = 0u32;
        for trun in track.trafs.iter().filter_map(|t| t.trun.as_ref()) {
            count = count
                .checked_add(trun.sample_count)
                .ok_or("trun sample counts overflow 32 bits")?;
            if let Some(&z) = trun.sample_sizes.iter().find(|&&z| z as u64 > file_len) {
                return Err(too_big("trun sample size", z as u64));
            }
        }
        if (count as usize) < track.trafs.len() {
            return Err(format!(
                "{} fragments hold {count} samples (fewer than one each)",
                track.trafs.len()
            ));
        }
        if count
            .checked_sub(1)
            .and_then(|n| n.checked_mul(track.default_sample_duration))
            .is_none()
        {
            return Err(format!(
                "{count} samples of default duration {} overflow 32 bits",
                track.default_sample_duration
            ));
        }
        return Ok(count);
    }
    let count = stbl.stsz.sample_count;
    if let Some(&z) = stbl
        .stsz
        .sample_sizes
        .iter()
        .find(|&&z| z as u64 > file_len)
    {
        return Err(too_big("stsz sample size", z as u64));
    }
    if stbl.stsz.sample_size as u64 > file_len {
        return Err(too_big("stsz sample size", stbl.stsz.sample_size as u64));
    }
    if let Some(e) = stbl
        .stsc
        .entries
        .iter()
        .find(|e| e.samples_per_chunk == 0 || e.first_chunk == 0)
    {
        return Err(format!(
            "stsc entry (first chunk {}, {} samples per chunk) needs both at least 1",
            e.first_chunk, e.samples_per_chunk
        ));
    }
    if let Some(co64) = &stbl.co64 {
        if let Some(&o) = co64.entries.iter().find(|&&o| o > file_len) {
            return Err(too_big("co64 chunk offset", o));
        }
    }
    // Every sample needs its stts entry (the crate unwraps it).
    let timed = stbl
        .stts
        .entries
        .iter()
        .fold(0u64, |a, e| a + e.sample_count as u64);
    if timed < count as u64 {
        return Err(format!(
            "stts gives times for {timed} samples, the track has {count}"
        ));
    }
    // The crate sums the entries (from 1) in 32 bits and unwraps an overflow.
    if timed >= u32::MAX as u64 {
        return Err(format!(
            "stts gives times for {timed} samples, more than 32 bits count"
        ));
    }
    Ok(count)
}

fn h264_track<'r>(
    path: &Path,
    reader: &'r mp4::Mp4Reader<Cursor<&[u8]>>,
) -> Result<&'r mp4::Mp4Track> {
    let mut ids: Vec<u32> = reader.tracks().keys().copied().collect();
    ids.sort_unstable();
    ids.iter()
        .filter_map(|id| reader.tracks().get(id))
        .find(|t| matches!(t.media_type(), Ok(mp4::MediaType::H264)))
        .ok_or_else(|| {
            Error::format(
                path,
                "video track codec",
                "H.264 (avc1)",
                "no H.264 video track",
            )
        })
}

/// Decode every frame of an H.264 mp4 to RGB, in display order.
pub fn read_mp4_frames(path: &Path) -> Result<Vec<RgbImage>> {
    let bytes = crate::io::limits::read_file(path)?;
    decode_mp4_frames(path, bytes)
}

/// [`read_mp4_frames`] on the file's bytes; `path` is used only in error messages.
pub fn decode_mp4_frames(path: &Path, bytes: Vec<u8>) -> Result<Vec<RgbImage>> {
    if let Some((c, _)) = video_sample_entries(&bytes)
        .into_iter()
        .find(|(c, _)| c != "avc1" && c != "avc3")
    {
        return Err(Error::format(
            path,
            "video track codec",
            "H.264 (avc1/avc3) as Cosmos and ffmpeg/libx264 write it (re-encode with \
             `ffmpeg -i IN -c:v libx264 -pix_fmt yuv420p OUT.mp4`)",
            format!("{c} ({})", codec_name(&c)),
        ));
    }
    let bytes = as_avc1(bytes);
    let mut reader = open_reader(path, &bytes)?;
    let track = h264_track(path, &reader)?;
    let track_id = track.track_id();
    let avcc = track
        .trak
        .mdia
        .minf
        .stbl
        .stsd
        .avc1
        .as_ref()
        .map(|a| a.avcc.clone())
        .ok_or_else(|| Error::format(path, "avc1/avcC", "an avcC box", "none"))?;
    let count = check_sample_table(track, bytes.len() as u64)
        .map_err(|e| Error::format(path, "mp4 sample table", "a consistent sample table", e))?;
    // Decoded frames must fit the decoded-size limit (checked before decoding anything).
    let (w, h) = (track.width() as u64, track.height() as u64);
    crate::io::limits::check_decoded(
        path,
        "decoded frames (width x height x 3 x samples)",
        w.saturating_mul(h)
            .saturating_mul(3)
            .saturating_mul(count as u64),
    )?;
    let len_size = (avcc.length_size_minus_one & 3) as usize + 1;
    let mut headers = Vec::new();
    for nal in avcc
        .sequence_parameter_sets
        .iter()
        .chain(&avcc.picture_parameter_sets)
    {
        headers.extend_from_slice(&[0, 0, 0, 1]);
        headers.extend_from_slice(&nal.bytes);
    }
    let mut samples = Vec::with_capacity((count as usize).min(bytes.len()));
    for sid in 1..=count {
        let sample = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            reader.read_sample(track_id, sid)
        }))
        .map_err(|_| {
            Error::format(
                path,
                format!("sample {sid}"),
                "a readable sample",
                "a sample table the demuxer could not follow",
            )
        })?
        .map_err(|e| {
            Error::format(
                path,
                format!("sample {sid}"),
                "a readable sample",
                e.to_string(),
            )
        })?
        .ok_or_else(|| Error::format(path, format!("sample {sid}"), "present", "missing"))?;
        samples.push(sample.bytes);
    }
    let frames = decode_h264_samples(path, &headers, &samples, len_size)?;
    if frames.len() != count as usize {
        return Err(Error::format(
            path,
            "decoded frames",
            format!("{count} frames (the track's sample count)"),
            format!("{}", frames.len()),
        ));
    }
    Ok(frames)
}

/// The NAL units of an H.264 mp4 in decode order: the avcC parameter sets, then every
/// sample's units (for building decoder test streams). None if it cannot be demuxed.
pub fn h264_access_units(bytes: &[u8]) -> Option<Vec<Vec<u8>>> {
    let bytes = as_avc1(bytes.to_vec());
    let mut reader = open_reader(Path::new("mp4"), &bytes).ok()?;
    let track = h264_track(Path::new("mp4"), &reader).ok()?;
    let (id, count) = (
        track.track_id(),
        check_sample_table(track, bytes.len() as u64).ok()?,
    );
    let avcc = track.trak.mdia.minf.stbl.stsd.avc1.as_ref()?.avcc.clone();
    let len_size = (avcc.length_size_minus_one & 3) as usize + 1;
    let mut out: Vec<Vec<u8>> = avcc
        .sequence_parameter_sets
        .iter()
        .chain(&avcc.picture_parameter_sets)
        .map(|n| n.bytes.clone())
        .collect();
    for sid in 1..=count {
        let sample = reader.read_sample(id, sid).ok()??;
        let mut s: &[u8] = &sample.bytes;
        while s.len() >= len_size {
            let n = s[..len_size]
                .iter()
                .fold(0usize, |a, &b| (a << 8) | b as usize);
            let nal = s.get(len_size..len_size + n)?;
            out.push(nal.to_vec());
            s = &s[len_size + n..];
        }
    }
    Some(out)
}

/// Decode a raw H.264 Annex B stream (start codes before each NAL unit), one NAL unit per
/// decoder call, through the same path as mp4 ingest.
pub fn decode_annexb(path: &Path, stream: &[u8]) -> Result<Vec<RgbImage>> {
    let samples: Vec<Vec<u8>> = split_annexb(stream)
        .into_iter()
        .map(|nal| {
            let mut s = (nal.len() as u32).to_be_bytes().to_vec();
            s.extend_from_slice(nal);
            s
        })
        .collect();
    decode_h264_samples(path, &[], &samples, 4)
}

/// Decode H.264 access units: `headers` (Annex B parameter sets, may be empty) then each
/// sample of length-prefixed NAL units (`len_size` bytes of big-endian length), as an mp4
/// stores them. Frames come back in display order. H.264 has no checksums: damaged slice
/// data that still parses decodes to different pictures, and only syntax errors are caught.
pub fn decode_h264_samples(
    path: &Path,
    headers: &[u8],
    samples: &[impl AsRef<[u8]>],
    len_size: usize,
) -> Result<Vec<RgbImage>> {
    let dec_err =
        |what: String| Error::format(path, what, "a decodable H.264 stream", "a decoder error");
    let mut decoder = Decoder::with_api_config(
        OpenH264API::from_source(),
        DecoderConfig::new().flush_after_decode(Flush::NoFlush),
    )
    .map_err(|e| Error::External {
        what: "OpenH264 decoder".into(),
        message: e.to_string(),
    })?;
    let opts = || DecodeOptions::new().flush_after_decode(Flush::NoFlush);
    let max = crate::io::limits::max_decoded_bytes();
    let mut decoded = 0u64;
    let mut frames = Vec::new();
    let mut push = |frames: &mut Vec<RgbImage>, img: RgbImage| -> Result<()> {
        decoded += img.as_raw().len() as u64;
        crate::io::limits::check_decoded(path, "decoded frames", decoded.min(max + 1))?;
        frames.push(img);
        Ok(())
    };
    if !headers.is_empty() {
        if let Some(y) = decoder
            .decode_with_options(headers, opts())
            .map_err(|e| dec_err(format!("avcC parameter sets ({e})")))?
        {
            push(&mut frames, i420_to_rgb(&y))?;
        }
    }
    let mut annexb = Vec::new();
    for (k, sample) in samples.iter().enumerate() {
        let sid = k + 1;
        annexb.clear();
        let mut s: &[u8] = sample.as_ref();
        while !s.is_empty() {
            if s.len() < len_size {
                return Err(Error::format(
                    path,
                    format!("sample {sid}"),
                    "length-prefixed NAL units",
                    "a truncated length",
                ));
            }
            let n = s[..len_size]
                .iter()
                .fold(0usize, |a, &b| (a << 8) | b as usize);
            s = &s[len_size..];
            if n > s.len() {
                return Err(Error::format(
                    path,
                    format!("sample {sid}"),
                    format!("a NAL unit of {n} bytes"),
                    format!("{} bytes left", s.len()),
                ));
            }
            annexb.extend_from_slice(&[0, 0, 0, 1]);
            annexb.extend_from_slice(&s[..n]);
            s = &s[n..];
        }
        if let Some(y) = decoder
            .decode_with_options(&annexb, opts())
            .map_err(|e| dec_err(format!("sample {sid} ({e})")))?
        {
            push(&mut frames, i420_to_rgb(&y))?;
        }
    }
    for y in decoder
        .flush_remaining()
        .map_err(|e| dec_err(format!("flush ({e})")))?
    {
        push(&mut frames, i420_to_rgb(&y))?;
    }
    Ok(frames)
}
