-- The user files a job's spec names (a hand's MJCF model and taxel layout, an object's mesh),
-- stored content-addressed like artifacts; task parameters name them by sha256.
CREATE TABLE job_assets (
    job_id      TEXT NOT NULL REFERENCES jobs (id),
    path        TEXT NOT NULL,  -- as the spec names it, relative to the spec file
    sha256      TEXT NOT NULL,
    size        BIGINT NOT NULL,
    media_type  TEXT NOT NULL,
    object_key  TEXT NOT NULL,
    PRIMARY KEY (job_id, path)
);
