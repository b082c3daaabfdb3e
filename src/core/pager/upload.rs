//! Writing an object to S3 (or any store speaking its API) with a multipart upload: parts of at
//! least [`MIN_PART_BYTES`] but the last, uploaded as they are made, so no machine holds the whole
//! object; an upload that fails is aborted, so no object appears. Requests are signed with
//! rusty-s3 where [`S3Config`] has credentials, unsigned otherwise.

use std::io::Read;
use std::time::Duration;

use rusty_s3::S3Action as _;

use super::remote::{s3_parts, S3Config};
use crate::error::{Error, Result};

/// The smallest part but the last (S3's limit).
pub const MIN_PART_BYTES: usize = 5 << 20;

/// An open multipart upload of one object.
pub struct MultipartUpload {
    location: String,
    agent: ureq::Agent,
    bucket: rusty_s3::Bucket,
    credentials: Option<rusty_s3::Credentials>,
    key: String,
    upload_id: String,
    /// ETag of part `k + 1`.
    etags: Vec<Option<String>>,
}

const SIGNED_FOR: Duration = Duration::from_secs(3600);

impl MultipartUpload {
    /// Starts uploading `location` (`s3://bucket/key`).
    pub fn start(location: &str, s3: &S3Config) -> Result<MultipartUpload> {
        let remote = |what: String| Error::remote(location, what);
        let Some((bucket, key)) = s3_parts(location)? else {
            return Err(remote("uploads go to s3://bucket/key".into()));
        };
        let (endpoint, style) = match &s3.endpoint {
            Some(e) => (e.clone(), rusty_s3::UrlStyle::Path),
            None => (format!("https://s3.{}.amazonaws.com", s3.region), rusty_s3::UrlStyle::VirtualHost),
        };
        let url = endpoint.parse().map_err(|e| remote(format!("bad S3 endpoint {endpoint:?}: {e}")))?;
        let bucket = rusty_s3::Bucket::new(url, style, bucket.to_string(), s3.region.clone())
            .map_err(|e| remote(format!("bad S3 endpoint {endpoint:?}: {e}")))?;
        let credentials = s3.credentials.as_ref().map(|(id, secret, token)| match token {
            Some(t) => rusty_s3::Credentials::new_with_token(id.clone(), secret.clone(), t.clone()),
            None => rusty_s3::Credentials::new(id.clone(), secret.clone()),
        });
        let agent: ureq::Agent = ureq::Agent::config_builder()
            .timeout_global(Some(Duration::from_secs(300)))
            .http_status_as_error(false)
            .build()
            .into();
        let mut up = MultipartUpload {
            location: location.into(),
            agent,
            bucket,
            credentials,
            key: key.into(),
            upload_id: String::new(),
            etags: Vec::new(),
        };
        let url = rusty_s3::actions::CreateMultipartUpload::new(&up.bucket, up.credentials.as_ref(), &up.key)
            .sign(SIGNED_FOR);
        let body = up.send("POST", url.as_str(), &[], "start the upload")?.1;
        let created = rusty_s3::actions::CreateMultipartUpload::parse_response(&body)
            .map_err(|e| remote(format!("unexpected answer to starting the upload: {e}")))?;
        up.upload_id = created.upload_id().to_string();
        Ok(up)
    }

    /// One request; its ETag header and body, or an error naming the location and the status.
    fn send(&self, method: &str, url: &str, body: &[u8], what: &str) -> Result<(Option<String>, String)> {
        let remote = |why: String| Error::remote(&self.location, format!("{what}: {why}"));
        let result = match method {
            "POST" => self.agent.post(url).send(body),
            "PUT" => self.agent.put(url).send(body),
            _ => self.agent.delete(url).call(),
        };
        let mut resp = result.map_err(|e| remote(e.to_string()))?;
        let status = resp.status().as_u16();
        let etag = resp.headers().get("etag").and_then(|v| v.to_str().ok()).map(str::to_string);
        let mut text = String::new();
        let _ = resp.body_mut().as_reader().take(1 << 20).read_to_string(&mut text);
        if !(200..300).contains(&status) {
            let code = text.split("<Code>").nth(1).and_then(|c| c.split('<').next()).unwrap_or("");
            return Err(remote(format!("HTTP {status} {code}").trim_end().to_string()));
        }
        Ok((etag, text))
    }

    /// Uploads part `number` (1-based; every part but the last at least [`MIN_PART_BYTES`]).
    pub fn part(&mut self, number: u16, bytes: &[u8]) -> Result<()> {
        let url = rusty_s3::actions::UploadPart::new(
            &self.bucket,
            self.credentials.as_ref(),
            &self.key,
            number,
            &self.upload_id,
        )
        .sign(SIGNED_FOR);
        let (etag, _) = self.send("PUT", url.as_str(), bytes, &format!("upload part {number}"))?;
        let etag =
            etag.ok_or_else(|| Error::remote(&self.location, format!("part {number}: no ETag in the answer")))?;
        let k = number as usize - 1;
        if self.etags.len() <= k {
            self.etags.resize(k + 1, None);
        }
        self.etags[k] = Some(etag);
        Ok(())
    }

    /// Completes the upload: the object appears, its parts in number order.
    pub fn complete(self) -> Result<()> {
        let Some(etags) = self.etags.iter().map(|e| e.as_deref()).collect::<Option<Vec<&str>>>() else {
            return Err(Error::remote(&self.location, "a part is missing"));
        };
        let action = rusty_s3::actions::CompleteMultipartUpload::new(
            &self.bucket,
            self.credentials.as_ref(),
            &self.key,
            &self.upload_id,
            etags.into_iter(),
        );
        let url = action.sign(SIGNED_FOR);
        let body = action.body();
        self.send("POST", url.as_str(), body.as_bytes(), "complete the upload").map(|_| ())
    }

    /// Abandons the upload (best effort): no object appears, the parts are dropped.
    pub fn abort(self) {
        let url = rusty_s3::actions::AbortMultipartUpload::new(
            &self.bucket,
            self.credentials.as_ref(),
            &self.key,
            &self.upload_id,
        )
        .sign(SIGNED_FOR);
        let _ = self.send("DELETE", url.as_str(), &[], "abort the upload");
    }
}
