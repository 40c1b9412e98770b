-- eyekey service schema, version 3: scoped operator tokens.
--
-- Each token has a name (recorded in the audit log for everything done with it) and scopes; only the
-- SHA-256 of the secret is stored. Revoked tokens stay as rows (revoked_at) so the audit log's names keep
-- meaning. The bootstrap operator token of the configuration is not stored here; it has the admin scope.
CREATE TABLE tokens (
    id           TEXT PRIMARY KEY NOT NULL,
    name         TEXT NOT NULL,
    scopes       TEXT NOT NULL,
    token_hash   BLOB NOT NULL UNIQUE,
    revoked_at   INTEGER,
    created_at   INTEGER NOT NULL
);
CREATE UNIQUE INDEX tokens_live_name ON tokens (name) WHERE revoked_at IS NULL;
CREATE INDEX tokens_by_creation ON tokens (created_at, id);
