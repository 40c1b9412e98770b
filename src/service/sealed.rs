//! Sealed objects at rest: the documents, evaluation reports, simulated views and frame bundles under the
//! data directory.
//!
//! Each object has a random [`DataKey`] of its own (one per document, one per job for all its outputs),
//! stored only wrapped by the master key in the object's row. Each file is sealed under it with
//! ChaCha20-Poly1305 and associated data naming the object and the file ([`document_aad`], [`job_file_aad`]),
//! so a sealed file moved to another name or row does not open. Files are written under a temporary name,
//! fsynced and renamed, so a crash never leaves a half-written object under its real name. Nothing a display
//! or an operator may not see is ever written in clear; plaintext exists only in memory, while a request is
//! served or a job runs.

use std::path::Path;

use super::crypto::{CryptoError, DataKey, MasterKey};
use super::store::documents::DocumentRow;
use super::store::jobs::JobRow;
use super::store::objects::Objects;
use eyekey_core::encoding::pipeline::EncodeOptions;

/// Suffix of every sealed file.
pub const SUFFIX: &str = ".sealed";

/// Associated data of a document's wrapped data key.
pub fn document_key_aad(id: &str) -> Vec<u8> {
    format!("eyekey-document-key:{id}").into_bytes()
}

/// Associated data of a document's sealed bytes.
pub fn document_aad(id: &str) -> Vec<u8> {
    format!("eyekey-document:{id}").into_bytes()
}

/// Associated data of a job's wrapped data key.
pub fn job_key_aad(id: &str) -> Vec<u8> {
    format!("eyekey-job-key:{id}").into_bytes()
}

/// Associated data of one of a job's sealed outputs (`name` relative to its output directory, e.g.
/// `frame_0.png` or `views/target.png`), or of its sealed options (`name` = `options`).
pub fn job_file_aad(id: &str, name: &str) -> Vec<u8> {
    format!("eyekey-job:{id}:{name}").into_bytes()
}

/// The key of a row's `data_key` column.
pub fn unwrap_key(master: &MasterKey, wrapped: Option<&[u8]>, aad: &[u8]) -> Result<DataKey, CryptoError> {
    DataKey::unwrap(master, wrapped.ok_or(CryptoError::Open)?, aad)
}

/// A job's data key, from its row (absent once the job is deleted).
pub fn job_key(master: &MasterKey, row: &JobRow) -> Result<DataKey, CryptoError> {
    unwrap_key(master, row.data_key.as_deref(), &job_key_aad(&row.id.to_string()))
}

/// The purpose under which upload digests are keyed ([`MasterKey::digest`]).
pub const DOCUMENT_MAC: &str = "document-content";

/// A document as stored: where its sealed file is, its wrapped data key and its keyed digest.
#[derive(Clone, Debug)]
pub struct StoredDocument {
    /// Path of the sealed file relative to the data directory.
    pub path: String,
    /// The data key, wrapped by the master key.
    pub data_key: Vec<u8>,
    /// Keyed HMAC-SHA256 of the bytes, hex.
    pub content_mac: String,
    /// The layout given with the bytes, sealed under the same data key (for `documents.sealed_layout`).
    pub sealed_layout: Option<Vec<u8>>,
}

/// Associated data of a document's sealed layout.
pub fn document_layout_aad(id: &str) -> Vec<u8> {
    format!("eyekey-document:{id}:layout").into_bytes()
}

/// A document's layout (a document rendered from text), opened under its data key; None for an upload.
pub fn document_layout(
    master: &MasterKey,
    doc: &DocumentRow,
) -> anyhow::Result<Option<eyekey_core::evaluation::DocumentText>> {
    let Some(sealed) = &doc.sealed_layout else {
        return Ok(None);
    };
    let key = unwrap_key(master, doc.data_key.as_deref(), &document_key_aad(&doc.id))?;
    let plain = key.open(sealed, &document_layout_aad(&doc.id))?;
    Ok(Some(serde_json::from_slice(&plain)?))
}

/// Seals a document's bytes (and the layout of one rendered from text, its `DocumentText` JSON) under a new data
/// key and stores the bytes as `documents/<id>.sealed`; the sealed layout is returned for the document's row.
pub async fn store_document(
    objects: &Objects,
    master: &MasterKey,
    id: &str,
    bytes: axum::body::Bytes,
    layout: Option<Vec<u8>>,
) -> std::io::Result<StoredDocument> {
    let (master, doc_id) = (master.clone(), id.to_string());
    let (sealed, data_key, content_mac, sealed_layout) = tokio::task::spawn_blocking(move || {
        let key = DataKey::generate();
        let data_key = key
            .wrap(&master, &document_key_aad(&doc_id))
            .map_err(std::io::Error::other)?;
        let sealed = key
            .seal(&bytes, &document_aad(&doc_id))
            .map_err(std::io::Error::other)?;
        let sealed_layout = layout
            .map(|l| key.seal(&l, &document_layout_aad(&doc_id)))
            .transpose()
            .map_err(std::io::Error::other)?;
        Ok::<_, std::io::Error>((sealed, data_key, master.digest(DOCUMENT_MAC, &bytes), sealed_layout))
    })
    .await
    .map_err(std::io::Error::other)??;
    let path = format!("documents/{id}{SUFFIX}");
    objects.write(&path, sealed).await?;
    Ok(StoredDocument {
        path,
        data_key,
        content_mac,
        sealed_layout,
    })
}

/// A document's bytes, opened from its sealed object.
pub async fn open_document(objects: &Objects, master: &MasterKey, doc: &DocumentRow) -> Result<Vec<u8>, OpenError> {
    let key = unwrap_key(master, doc.data_key.as_deref(), &document_key_aad(&doc.id)).map_err(|_| OpenError::Open)?;
    open_object(objects, &doc.path, &key, &document_aad(&doc.id)).await
}

/// Reads and opens a sealed object.
pub async fn open_object(objects: &Objects, name: &str, key: &DataKey, aad: &[u8]) -> Result<Vec<u8>, OpenError> {
    match objects.read(name).await {
        Ok(Some(sealed)) => key.open(&sealed, aad).map_err(|_| OpenError::Open),
        Ok(None) => Err(OpenError::Missing),
        Err(e) => Err(OpenError::Io(e)),
    }
}

/// Writes `bytes` (already sealed) to `path`: into `.<name>.part` beside it, fsynced, then renamed, and the
/// directory synced. The parent directory must exist.
pub fn write_file(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let parent = path
        .parent()
        .ok_or_else(|| std::io::Error::other("a sealed file needs a directory"))?;
    let name = path
        .file_name()
        .and_then(|n| n.to_str())
        .ok_or_else(|| std::io::Error::other("a sealed file needs a plain name"))?;
    let part = parent.join(format!(".{name}.part"));
    let _ = std::fs::remove_file(&part);
    let written = eyekey_core::bundle::create_synced(&part, bytes).and_then(|()| std::fs::rename(&part, path));
    if let Err(e) = written {
        let _ = std::fs::remove_file(&part);
        return Err(e);
    }
    eyekey_core::bundle::fsync_dir(parent)
}

/// Seals `plain` under `key` for `aad` and writes it to `path` (see [`write_file`]).
pub fn seal_to_file(path: &Path, key: &DataKey, aad: &[u8], plain: &[u8]) -> std::io::Result<()> {
    let sealed = key.seal(plain, aad).map_err(std::io::Error::other)?;
    write_file(path, &sealed)
}

/// The part of a job's options sealed under its key (`jobs.sealed_options`): the document's text hint and the
/// encoder's seed. Either gives away what the frames hide: the text is the secret itself, and the seed is the
/// decoys' noise, which an attacker who knew it could subtract.
#[derive(serde::Serialize, serde::Deserialize)]
struct SecretOptions {
    #[serde(default)]
    document_text: Option<eyekey_core::evaluation::DocumentText>,
    #[serde(default)]
    seed: Option<u64>,
}

/// A job's options split for storage: the JSON kept in clear (`jobs.options`), without the document's text hint
/// or the seed, and, when the options carry either, their JSON, to be sealed (`jobs.sealed_options`).
pub fn split_options(options: &EncodeOptions) -> serde_json::Result<(String, Option<Vec<u8>>)> {
    let secret = SecretOptions {
        document_text: options.document_text.clone(),
        seed: options.seed,
    };
    let secret = match (&secret.document_text, secret.seed) {
        (None, None) => None,
        _ => Some(serde_json::to_vec(&secret)?),
    };
    let clear = EncodeOptions {
        document_text: None,
        seed: None,
        ..options.clone()
    };
    Ok((serde_json::to_string(&clear)?, secret))
}

/// The options [`split_options`] split, joined again (`secret` already opened). A sealed part that is a bare
/// text hint, as jobs stored before the seed was sealed hold, is read as such (their seed is in the clear part).
pub fn join_options(clear: &str, secret: Option<&[u8]>) -> serde_json::Result<EncodeOptions> {
    let mut options: EncodeOptions = serde_json::from_str(clear)?;
    if let Some(secret) = secret {
        let value: serde_json::Value = serde_json::from_slice(secret)?;
        if value.get("lines").is_some() {
            // A bare text hint, as sealed before the seed was.
            options.document_text = Some(serde_json::from_value(value)?);
        } else {
            let s: SecretOptions = serde_json::from_value(value)?;
            options.document_text = s.document_text;
            options.seed = s.seed.or(options.seed);
        }
    }
    Ok(options)
}

/// Associated data of a job's sealed options.
pub fn job_options_aad(id: &str) -> Vec<u8> {
    job_file_aad(id, "options")
}

/// Associated data of a job's sealed evaluation summary.
pub fn job_summary_aad(id: &str) -> Vec<u8> {
    job_file_aad(id, "summary")
}

/// Opens one of a job row's sealed fields (`name`: `options` or `summary`) under the job's key.
fn open_job_field(master: &MasterKey, row: &JobRow, name: &str, sealed: &[u8]) -> Result<Vec<u8>, CryptoError> {
    job_key(master, row)?.open(sealed, &job_file_aad(&row.id.to_string(), name))
}

/// A job's full options: the clear part joined with the sealed part, opened under the job's key.
pub fn job_options(master: &MasterKey, row: &JobRow) -> anyhow::Result<EncodeOptions> {
    let secret = match &row.sealed_options {
        Some(sealed) => Some(open_job_field(master, row, "options", sealed)?),
        None => None,
    };
    Ok(join_options(&row.options, secret.as_deref())?)
}

/// A job's evaluation summary, opened under the job's key (or, for a job stored before summaries were
/// sealed, as stored).
pub fn job_summary(master: &MasterKey, row: &JobRow) -> anyhow::Result<Option<serde_json::Value>> {
    let text = match (&row.sealed_summary, &row.evaluation_summary) {
        (Some(sealed), _) => open_job_field(master, row, "summary", sealed)?,
        (None, Some(clear)) => clear.as_bytes().to_vec(),
        (None, None) => return Ok(None),
    };
    Ok(Some(serde_json::from_slice(&text)?))
}

/// Why a sealed file could not be read.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// There is no such file.
    #[error("no such sealed file")]
    Missing,
    /// It could not be read.
    #[error("reading a sealed file: {0}")]
    Io(std::io::Error),
    /// It did not authenticate: damaged, moved, or its key is gone.
    #[error("a sealed file did not authenticate (damaged, moved, or its key was deleted)")]
    Open,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sealed_file_holds_no_plaintext_and_opens_only_under_its_own_name() {
        let dir = tempfile::tempdir().unwrap();
        let key = DataKey::generate();
        let path = dir.path().join("d1.sealed");
        seal_to_file(&path, &key, &document_aad("d1"), b"PIN 4821 PIN 4821").unwrap();
        let on_disk = std::fs::read(&path).unwrap();
        assert!(!on_disk.windows(4).any(|w| w == b"4821"));
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["d1.sealed"], "no temporary file left");
        let objects = Objects::Dir(dir.path().to_path_buf());
        let rt = tokio::runtime::Builder::new_current_thread().build().unwrap();
        assert_eq!(
            rt.block_on(open_object(&objects, "d1.sealed", &key, &document_aad("d1")))
                .unwrap(),
            b"PIN 4821 PIN 4821"
        );
        assert!(matches!(
            rt.block_on(open_object(&objects, "d1.sealed", &key, &document_aad("d2"))),
            Err(OpenError::Open)
        ));
        assert!(matches!(
            rt.block_on(open_object(&objects, "nope", &key, b"")),
            Err(OpenError::Missing)
        ));
    }

    #[test]
    fn options_keep_the_document_text_and_the_seed_out_of_the_clear_part_and_join_back_whole() {
        let options = EncodeOptions {
            document_text: Some(eyekey_core::evaluation::DocumentText {
                lines: vec!["PIN".into(), "4821".into()],
                scale: 4,
                alphabet: "0123456789".into(),
            }),
            seed: Some(0x5EC2_E75E_ED00_u64),
            ..Default::default()
        };
        let (clear, secret) = split_options(&options).unwrap();
        assert!(!clear.contains("4821"), "{clear}");
        let clear_json: serde_json::Value = serde_json::from_str(&clear).unwrap();
        assert_eq!(clear_json["seed"], serde_json::Value::Null, "{clear}");
        assert!(!clear.contains(&0x5EC2_E75E_ED00_u64.to_string()), "{clear}");
        let secret_text = String::from_utf8(secret.clone().unwrap()).unwrap();
        assert!(secret_text.contains("4821") && secret_text.contains(&0x5EC2_E75E_ED00_u64.to_string()));
        let back = join_options(&clear, secret.as_deref()).unwrap();
        assert_eq!(back, options);
        // A seed alone is sealed too.
        let seeded = EncodeOptions {
            seed: Some(7),
            ..Default::default()
        };
        let (clear, secret) = split_options(&seeded).unwrap();
        assert!(secret.is_some());
        assert_eq!(join_options(&clear, secret.as_deref()).unwrap(), seeded);
        let (clear, secret) = split_options(&EncodeOptions::default()).unwrap();
        assert!(secret.is_none());
        assert_eq!(join_options(&clear, None).unwrap(), EncodeOptions::default());
    }

    #[test]
    fn a_job_stored_with_a_bare_text_hint_and_a_clear_seed_still_opens() {
        let hint = eyekey_core::evaluation::DocumentText {
            lines: vec!["PIN".into(), "4821".into()],
            scale: 4,
            alphabet: "0123456789".into(),
        };
        let clear = serde_json::json!({ "seed": 1 }).to_string();
        let secret = serde_json::to_vec(&hint).unwrap();
        let back = join_options(&clear, Some(&secret)).unwrap();
        assert_eq!(back.seed, Some(1));
        assert_eq!(back.document_text, Some(hint));
    }
}
