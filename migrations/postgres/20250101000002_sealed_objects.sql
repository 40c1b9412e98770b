-- eyekey service schema, version 2 (PostgreSQL): documents and job outputs sealed at rest, deletion and expiry.
--
-- Every document and every file a job produces is sealed with ChaCha20-Poly1305 under a random data key
-- of its own; the data key is stored only here, wrapped (sealed) by the master key. Deleting a row's
-- data_key destroys the object wherever its ciphertext still lies. Rows whose data_key is NULL and whose
-- deleted_at is NULL were written before this version; the service seals them at start.

-- A keyed HMAC-SHA256 of the upload under a key derived from the master key, never a plain hash: the plain
-- hash of a PIN slip gives the PIN to anyone who can render the candidates.
ALTER TABLE documents RENAME COLUMN sha256 TO content_mac;
ALTER TABLE documents ADD COLUMN data_key BYTEA;
ALTER TABLE documents ADD COLUMN deleted_at BIGINT;

-- The job's data key seals its outputs and sealed_options: the parts of its options that carry the
-- document (its text hint); `options` keeps the rest in clear.
ALTER TABLE jobs ADD COLUMN data_key BYTEA;
ALTER TABLE jobs ADD COLUMN sealed_options BYTEA;
-- The evaluation summary, sealed too: it holds what the attackers read off the views (the document's text
-- when they succeed). evaluation_summary stays only for jobs stored before this version, until sealed.
ALTER TABLE jobs ADD COLUMN sealed_summary BYTEA;
ALTER TABLE jobs ADD COLUMN deleted_at BIGINT;
CREATE INDEX jobs_by_document ON jobs (document_id);
CREATE INDEX jobs_by_profile ON jobs (profile_id);
