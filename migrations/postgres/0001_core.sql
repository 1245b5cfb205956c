-- vint core schema: jobs, tasks and their dependencies, attempts, artifacts, lineage, samples.
-- The Postgres and SQLite files are kept identical in meaning; times are Unix milliseconds.

CREATE TABLE jobs (
    id               TEXT PRIMARY KEY,
    name             TEXT NOT NULL,
    seed             BIGINT NOT NULL,
    spec_toml        TEXT NOT NULL,
    idempotency_key  TEXT NOT NULL UNIQUE,
    state            TEXT NOT NULL,
    created_ms       BIGINT NOT NULL,
    finished_ms      BIGINT
);

CREATE TABLE tasks (
    id                 TEXT PRIMARY KEY,           -- job id || '/' || key
    job_id             TEXT NOT NULL REFERENCES jobs (id),
    key                TEXT NOT NULL,
    stage              TEXT NOT NULL,
    priority           BIGINT NOT NULL,            -- lower leases first
    params_json        TEXT NOT NULL,
    state              TEXT NOT NULL,
    deps_pending       BIGINT NOT NULL,            -- dependencies not yet succeeded
    attempt            BIGINT NOT NULL DEFAULT 0,  -- attempts started so far
    max_attempts       BIGINT NOT NULL,
    not_before_ms      BIGINT NOT NULL DEFAULT 0,  -- retry backoff
    lease_owner        TEXT,
    lease_deadline_ms  BIGINT,
    last_error         TEXT,
    engine_json        TEXT,                       -- engine that produced the outputs
    result_json        TEXT,
    created_ms         BIGINT NOT NULL,
    updated_ms         BIGINT NOT NULL,
    UNIQUE (job_id, key)
);
-- Partial indexes keep the dequeue and reaper scans proportional to live work, not history.
CREATE INDEX tasks_ready ON tasks (priority, created_ms, id) WHERE state = 'queued';
CREATE INDEX tasks_leased ON tasks (lease_deadline_ms) WHERE state = 'running';
CREATE INDEX tasks_job_state ON tasks (job_id, state);

CREATE TABLE task_deps (
    task_id     TEXT NOT NULL REFERENCES tasks (id),
    depends_on  TEXT NOT NULL REFERENCES tasks (id),
    PRIMARY KEY (task_id, depends_on)
);
CREATE INDEX task_deps_by_dependency ON task_deps (depends_on);

CREATE TABLE attempts (
    task_id       TEXT NOT NULL REFERENCES tasks (id),
    attempt       BIGINT NOT NULL,
    worker_id     TEXT NOT NULL,
    started_ms    BIGINT NOT NULL,
    ended_ms      BIGINT,
    outcome       TEXT,                -- succeeded | failed | retry | lease_expired | cancelled
    error         TEXT,
    engine_json   TEXT,
    timings_json  TEXT,
    PRIMARY KEY (task_id, attempt)
);

CREATE TABLE artifacts (
    task_id     TEXT NOT NULL REFERENCES tasks (id),
    name        TEXT NOT NULL,
    sha256      TEXT NOT NULL,
    size        BIGINT NOT NULL,
    media_type  TEXT NOT NULL,
    object_key  TEXT NOT NULL,
    created_ms  BIGINT NOT NULL,
    PRIMARY KEY (task_id, name)
);
CREATE INDEX artifacts_by_sha ON artifacts (sha256);

-- Which artifacts a task consumed: the edges of the lineage graph (outputs are artifacts.task_id).
CREATE TABLE lineage_edges (
    task_id        TEXT NOT NULL REFERENCES tasks (id),
    input_task_id  TEXT NOT NULL REFERENCES tasks (id),
    input_name     TEXT NOT NULL,
    input_sha256   TEXT NOT NULL,
    PRIMARY KEY (task_id, input_task_id, input_name)
);

-- Packaged samples; their files are the artifacts of package_task_id named '<sample_id>/<file>'.
CREATE TABLE samples (
    job_id           TEXT NOT NULL REFERENCES jobs (id),
    sample_id        TEXT NOT NULL,
    package_task_id  TEXT NOT NULL REFERENCES tasks (id),
    PRIMARY KEY (job_id, sample_id)
);
