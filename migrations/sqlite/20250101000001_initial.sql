-- eyekey service schema, version 1. Times are Unix milliseconds (UTC); ids are UUID text.

-- Service-wide values, e.g. a value sealed under the master key to detect a changed key at start-up.
CREATE TABLE settings (
    name       TEXT PRIMARY KEY NOT NULL,
    value      BLOB NOT NULL,
    created_at INTEGER NOT NULL
);

-- One row per enrolled person. The profile itself lives only in profile_versions, sealed.
-- Deleting a profile deletes its versions (the ciphertexts) and keeps this row as a tombstone, so the
-- jobs that used it still say which profile and version they used.
CREATE TABLE profiles (
    id              TEXT PRIMARY KEY NOT NULL,
    label           TEXT,
    current_version INTEGER NOT NULL,
    deleted_at      INTEGER,
    created_at      INTEGER NOT NULL,
    updated_at      INTEGER NOT NULL
);
CREATE INDEX profiles_by_creation ON profiles (created_at, id);

-- Every enrolment of a profile is a new version (like a key rotation); versions are kept so a job
-- keeps the version it was created with. ciphertext = ChaCha20-Poly1305(profile JSON) under the
-- master key, associated data "eyekey-profile:{profile_id}:{version}".
CREATE TABLE profile_versions (
    profile_id TEXT NOT NULL REFERENCES profiles (id),
    version    INTEGER NOT NULL,
    nonce      BLOB NOT NULL,
    ciphertext BLOB NOT NULL,
    created_at INTEGER NOT NULL,
    PRIMARY KEY (profile_id, version)
);

-- Registered light-field displays. Only the SHA-256 of the access token is stored.
CREATE TABLE displays (
    id               TEXT PRIMARY KEY NOT NULL,
    name             TEXT NOT NULL,
    geometry         TEXT NOT NULL,
    token_hash       BLOB NOT NULL UNIQUE,
    token_rotated_at INTEGER NOT NULL,
    deleted_at       INTEGER,
    created_at       INTEGER NOT NULL
);
CREATE INDEX displays_by_creation ON displays (created_at, id);

-- Uploaded documents; the bytes are a file under the data directory (path is relative to it).
CREATE TABLE documents (
    id           TEXT PRIMARY KEY NOT NULL,
    sha256       TEXT NOT NULL,
    content_type TEXT NOT NULL,
    bytes        INTEGER NOT NULL,
    width        INTEGER NOT NULL,
    height       INTEGER NOT NULL,
    path         TEXT NOT NULL,
    created_at   INTEGER NOT NULL
);
CREATE INDEX documents_by_creation ON documents (created_at, id);

-- The durable job queue. state: queued -> running -> succeeded | failed | cancelled.
-- A worker owns a running job while lease_until is in the future; attempts counts claims.
CREATE TABLE jobs (
    id                 TEXT PRIMARY KEY NOT NULL,
    display_id         TEXT NOT NULL REFERENCES displays (id),
    document_id        TEXT NOT NULL REFERENCES documents (id),
    decoy_document_id  TEXT REFERENCES documents (id),
    profile_id         TEXT NOT NULL REFERENCES profiles (id),
    profile_version    INTEGER NOT NULL,
    observers          TEXT NOT NULL,
    method             TEXT NOT NULL,
    options            TEXT NOT NULL,
    state              TEXT NOT NULL
                       CHECK (state IN ('queued', 'running', 'succeeded', 'failed', 'cancelled')),
    progress           REAL NOT NULL DEFAULT 0,
    attempts           INTEGER NOT NULL DEFAULT 0,
    max_attempts       INTEGER NOT NULL,
    lease_until        INTEGER,
    heartbeat_at       INTEGER,
    worker_id          TEXT,
    last_error         TEXT,
    cancel_requested   INTEGER NOT NULL DEFAULT 0,
    idempotency_key    TEXT UNIQUE,
    request_hash       TEXT NOT NULL,
    evaluation_summary TEXT,
    bundle_path        TEXT,
    bundle_files       TEXT,
    created_at         INTEGER NOT NULL,
    started_at         INTEGER,
    finished_at        INTEGER,
    solve_ms           INTEGER,
    updated_at         INTEGER NOT NULL
);
CREATE INDEX jobs_by_state ON jobs (state, created_at, id);
CREATE INDEX jobs_by_display ON jobs (display_id, created_at, id);
CREATE INDEX jobs_by_creation ON jobs (created_at, id);

-- Who did what to which resource, and when. Never the contents of a profile.
CREATE TABLE audit_log (
    id         INTEGER PRIMARY KEY AUTOINCREMENT,
    actor      TEXT NOT NULL,
    action     TEXT NOT NULL,
    resource   TEXT NOT NULL,
    created_at INTEGER NOT NULL
);

-- The audit log is append-only.
CREATE TRIGGER audit_log_no_update BEFORE UPDATE ON audit_log
BEGIN
    SELECT RAISE(ABORT, 'audit_log is append-only');
END;
CREATE TRIGGER audit_log_no_delete BEFORE DELETE ON audit_log
BEGIN
    SELECT RAISE(ABORT, 'audit_log is append-only');
END;
