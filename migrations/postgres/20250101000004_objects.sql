-- eyekey service schema, version 4 (PostgreSQL only): sealed objects in the database.
--
-- With SQLite, documents and job outputs are sealed files under the data directory. With PostgreSQL,
-- several API processes and workers on several machines must all reach them, so they are rows here, named
-- by the same relative paths (documents/<id>.sealed, jobs/<job>-<attempt>/<file>.sealed). Each is sealed
-- under its object's data key before it is written; deleting the row's owner destroys its key.
CREATE TABLE objects (
    path       TEXT PRIMARY KEY NOT NULL,
    data       BYTEA NOT NULL,
    created_at BIGINT NOT NULL
);
