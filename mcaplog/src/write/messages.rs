//! The kinds of message a [`RunLog`] logs: JSON objects, images, 3D scenes and log lines.

use prost::Message as _;
use serde::Serialize;

use super::state::Kind;
use super::{RunLog, topic_err};
use crate::foxglove;
use crate::{LOG_TOPIC, LogLevel, Result, now_ns};

impl RunLog {
    /// Logs `value` (which must serialize to a JSON object) on `topic`, timestamped now.
    pub fn json<T: Serialize + ?Sized>(&self, topic: &str, value: &T) -> Result<()> {
        self.json_at(topic, now_ns(), value)
    }

    /// Logs `value` (which must serialize to a JSON object) on `topic` at `time_ns`.
    pub fn json_at<T: Serialize + ?Sized>(
        &self,
        topic: &str,
        time_ns: u64,
        value: &T,
    ) -> Result<()> {
        if !self.enabled() {
            return Ok(());
        }
        let path = &self.shared.path;
        let data = serde_json::to_vec(value)
            .map_err(|e| topic_err(path, topic, format!("cannot encode as JSON: {e}")))?;
        if data.first() != Some(&b'{') {
            return Err(topic_err(
                path,
                topic,
                "a JSON message must be an object".into(),
            ));
        }
        self.write(topic, Kind::Json, time_ns, &data)
    }

    /// Logs an uncompressed image as `foxglove.RawImage` at `timestamp_ns`. `encoding` is one
    /// of `rgb8`, `bgr8`, `rgba8`, `bgra8`, `mono8`, `mono16` (little-endian) or `32FC1`
    /// (little-endian f32, shown as brightness from 0 to 1); `data` holds the rows without
    /// padding.
    pub fn raw_image(
        &self,
        topic: &str,
        timestamp_ns: u64,
        width: u32,
        height: u32,
        encoding: &str,
        data: &[u8],
    ) -> Result<()> {
        if !self.enabled() {
            return Ok(());
        }
        let path = &self.shared.path;
        let bytes_per_pixel = match encoding {
            "mono8" | "8UC1" => 1,
            "mono16" | "16UC1" => 2,
            "rgb8" | "bgr8" => 3,
            "rgba8" | "bgra8" | "32FC1" => 4,
            other => {
                return Err(topic_err(
                    path,
                    topic,
                    format!(
                        "unsupported image encoding {other:?} (rgb8, bgr8, rgba8, bgra8, mono8, mono16, 32FC1)"
                    ),
                ));
            }
        };
        let step = width as usize * bytes_per_pixel;
        if data.len() != step * height as usize {
            return Err(topic_err(
                path,
                topic,
                format!(
                    "a {width}x{height} {encoding} image has {} bytes, not {}",
                    step * height as usize,
                    data.len()
                ),
            ));
        }
        let message = foxglove::RawImage {
            timestamp: Some(foxglove::timestamp(timestamp_ns)),
            frame_id: String::new(),
            width,
            height,
            encoding: encoding.to_string(),
            step: step as u32,
            data: data.to_vec(),
        };
        self.write(
            topic,
            Kind::RawImage,
            timestamp_ns,
            &message.encode_to_vec(),
        )
    }

    /// Logs an encoded image (`format`: `png`, `jpeg`, `webp` or `avif`) as
    /// `foxglove.CompressedImage` at `timestamp_ns`.
    pub fn compressed_image(
        &self,
        topic: &str,
        timestamp_ns: u64,
        format: &str,
        data: &[u8],
    ) -> Result<()> {
        if !self.enabled() {
            return Ok(());
        }
        let message = foxglove::CompressedImage {
            timestamp: Some(foxglove::timestamp(timestamp_ns)),
            frame_id: String::new(),
            data: data.to_vec(),
            format: format.to_string(),
        };
        self.write(
            topic,
            Kind::CompressedImage,
            timestamp_ns,
            &message.encode_to_vec(),
        )
    }

    /// Logs a 3D scene as `foxglove.SceneUpdate` at `timestamp_ns`.
    pub fn scene_update(
        &self,
        topic: &str,
        timestamp_ns: u64,
        update: &foxglove::SceneUpdate,
    ) -> Result<()> {
        if !self.enabled() {
            return Ok(());
        }
        self.write(
            topic,
            Kind::SceneUpdate,
            timestamp_ns,
            &update.encode_to_vec(),
        )
    }

    /// Logs a line as `foxglove.Log` on [`LOG_TOPIC`], named with the process, timestamped now.
    pub fn log_line(&self, level: LogLevel, message: &str) -> Result<()> {
        if !self.enabled() {
            return Ok(());
        }
        let time_ns = now_ns();
        let line = foxglove::Log {
            timestamp: Some(foxglove::timestamp(time_ns)),
            level: level as i32,
            message: message.to_string(),
            name: self.process.clone(),
            file: String::new(),
            line: 0,
        };
        self.write(LOG_TOPIC, Kind::Log, time_ns, &line.encode_to_vec())
    }
}
