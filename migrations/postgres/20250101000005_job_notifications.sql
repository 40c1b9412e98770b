-- eyekey service schema, version 5 (PostgreSQL only): every change of a job is announced.
--
-- API and worker processes each LISTEN on the channel eyekey_jobs: an API process forwards the changes to
-- its event streams (a job's progress, a display's new bundle), whichever process made them; an idle
-- worker wakes when a job is queued. The payload names the job, never its contents. Notifications are
-- delivered when the changing transaction commits.
CREATE FUNCTION jobs_notify() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
    PERFORM pg_notify('eyekey_jobs', json_build_object(
        'id', NEW.id, 'display_id', NEW.display_id, 'state', NEW.state, 'progress', NEW.progress)::text);
    RETURN NULL;
END;
$$;
CREATE TRIGGER jobs_changed AFTER INSERT OR UPDATE ON jobs
    FOR EACH ROW EXECUTE FUNCTION jobs_notify();
