-- eyekey service schema, version 6: a document rendered from text keeps its layout (lines, font scale, secret
-- alphabet), sealed under the document's own key, so that jobs on it are judged by the known-font attacker
-- without the operator repeating the text. NULL for uploaded images. Cleared when the document is deleted.
ALTER TABLE documents ADD COLUMN sealed_layout BLOB;
