-- eyekey service schema, version 1, for PostgreSQL: the same tables as migrations/sqlite, in PostgreSQL's
-- types (INTEGER → BIGINT, REAL → DOUBLE PRECISION, BLOB → BYTEA). Times are Unix milliseconds (UTC);
-- ids are UUID text.

-- Service-wide values, e.g. a value sealed under the master key to detect a changed key at start-up.
CREATE TABLE settings (
    name       TEXT PRIMARY KEY NOT NULL,
    value      BYTEA NOT NULL,
    created_at BIGINT NOT NULL
);

-- One row per enrolled person. The profile itself lives only in profile_versions, sealed.
CREATE TABLE profiles (
    id              TEXT PRIMARY KEY NOT NULL,
    label           TEXT,
    current_version BIGINT NOT NULL,
    deleted_at      BIGINT,
    created_at      BIGINT NOT NULL,
    updated_at      BIGINT NOT NULL
);
CREATE INDEX profiles_by_creation ON profiles (created_at, id);

-- Every enrolment of a profile is a new version; ciphertext = ChaCha20-Poly1305(profile JSON) under the
-- master key, associated data "eyekey-profile:{profile_id}:{version}".
CREATE TABLE profile_versions (
    profile_id TEXT NOT NULL REFERENCES profiles (id),
    version    BIGINT NOT NULL,
    nonce      BYTEA NOT NULL,
    ciphertext BYTEA NOT NULL,
    created_at BIGINT NOT NULL,
    PRIMARY KEY (profile_id, version)
);

-- Registered light-field displays. Only the SHA-256 of the access token is stored.
CREATE TABLE displays (
    id               TEXT PRIMARY KEY NOT NULL,
    name             TEXT NOT NULL,
    geometry         TEXT NOT NULL,
    token_hash       BYTEA NOT NULL UNIQUE,
    token_rotated_at BIGINT NOT NULL,
    deleted_at       BIGINT,
    created_at       BIGINT NOT NULL
);
CREATE INDEX displays_by_creation ON displays (created_at, id);

-- Uploaded documents; the bytes are an object (see migration 4) named by path.
CREATE TABLE documents (
    id           TEXT PRIMARY KEY NOT NULL,
    sha256       TEXT NOT NULL,
    content_type TEXT NOT NULL,
    bytes        BIGINT NOT NULL,
    width        BIGINT NOT NULL,
    height       BIGINT NOT NULL,
    path         TEXT NOT NULL,
    created_at   BIGINT NOT NULL
);
CREATE INDEX documents_by_creation ON documents (created_at, id);

-- The durable job queue. state: queued -> running -> succeeded | failed | cancelled.
-- A worker owns a running job while lease_until is in the future; attempts counts claims. Workers claim
-- with SELECT … FOR UPDATE SKIP LOCKED.
CREATE TABLE jobs (
    id                 TEXT PRIMARY KEY NOT NULL,
    display_id         TEXT NOT NULL REFERENCES displays (id),
    document_id        TEXT NOT NULL REFERENCES documents (id),
    decoy_document_id  TEXT REFERENCES documents (id),
    profile_id         TEXT NOT NULL REFERENCES profiles (id),
    profile_version    BIGINT NOT NULL,
    observers          TEXT NOT NULL,
    method             TEXT NOT NULL,
    options            TEXT NOT NULL,
    state              TEXT NOT NULL
                       CHECK (state IN ('queued', 'running', 'succeeded', 'failed', 'cancelled')),
    progress           DOUBLE PRECISION NOT NULL DEFAULT 0,
    attempts           BIGINT NOT NULL DEFAULT 0,
    max_attempts       BIGINT NOT NULL,
    lease_until        BIGINT,
    heartbeat_at       BIGINT,
    worker_id          TEXT,
    last_error         TEXT,
    cancel_requested   BIGINT NOT NULL DEFAULT 0,
    idempotency_key    TEXT UNIQUE,
    request_hash       TEXT NOT NULL,
    evaluation_summary TEXT,
    bundle_path        TEXT,
    bundle_files       TEXT,
    created_at         BIGINT NOT NULL,
    started_at         BIGINT,
    finished_at        BIGINT,
    solve_ms           BIGINT,
    updated_at         BIGINT NOT NULL
);
CREATE INDEX jobs_by_state ON jobs (state, created_at, id);
CREATE INDEX jobs_by_display ON jobs (display_id, created_at, id);
CREATE INDEX jobs_by_creation ON jobs (created_at, id);

-- Who did what to which resource, and when. Never the contents of a profile.
CREATE TABLE audit_log (
    id         BIGINT GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
    actor      TEXT NOT NULL,
    action     TEXT NOT NULL,
    resource   TEXT NOT NULL,
    created_at BIGINT NOT NULL
);

-- The audit log is append-only.
CREATE FUNCTION audit_log_append_only() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
    RAISE EXCEPTION 'audit_log is append-only';
END;
$$;
CREATE TRIGGER audit_log_no_update BEFORE UPDATE ON audit_log
    FOR EACH ROW EXECUTE FUNCTION audit_log_append_only();
CREATE TRIGGER audit_log_no_delete BEFORE DELETE ON audit_log
    FOR EACH ROW EXECUTE FUNCTION audit_log_append_only();
CREATE TRIGGER audit_log_no_truncate BEFORE TRUNCATE ON audit_log
    FOR EACH STATEMENT EXECUTE FUNCTION audit_log_append_only();
