-- Worldline lineage warehouse, schema version 1. The only DDL in the project.
-- Every id is deterministic (a hash of what the row stands for), so re-runs insert nothing new.
CREATE TABLE IF NOT EXISTS worldline_meta (
    key   VARCHAR PRIMARY KEY,
    value VARCHAR NOT NULL
);

CREATE TABLE IF NOT EXISTS manifests (
    manifest_hash  VARCHAR PRIMARY KEY,   -- sha256 of the canonical JSON of its meaning
    name           VARCHAR NOT NULL,
    schema_version INTEGER NOT NULL,
    body           JSON NOT NULL,         -- the whole manifest, canonical JSON
    source_uri     VARCHAR,               -- the YAML file it was read from, if any
    parent_hash    VARCHAR,               -- the manifest it was derived from (the loop)
    recorded_at    TIMESTAMP NOT NULL DEFAULT current_timestamp
);

CREATE TABLE IF NOT EXISTS runs (
    run_id              VARCHAR PRIMARY KEY,
    flow                VARCHAR NOT NULL,
    manifest_hash       VARCHAR,
    prefect_flow_run_id VARCHAR,
    status              VARCHAR NOT NULL,  -- running | completed | partial | failed
    params              JSON,
    message             VARCHAR,
    started_at          TIMESTAMP NOT NULL DEFAULT current_timestamp,
    ended_at            TIMESTAMP
);

CREATE TABLE IF NOT EXISTS stage_runs (
    stage_run_id  VARCHAR PRIMARY KEY,   -- hash of (stage, input_key): one row per unit of work
    run_id        VARCHAR NOT NULL,      -- the run that did the work
    stage         VARCHAR NOT NULL,
    input_key     VARCHAR NOT NULL,      -- hash of inputs and stage config
    manifest_hash VARCHAR,
    status        VARCHAR NOT NULL,
    n_in          BIGINT NOT NULL DEFAULT 0,
    n_out         BIGINT NOT NULL DEFAULT 0,
    seconds       DOUBLE NOT NULL DEFAULT 0,
    attrs         JSON,
    recorded_at   TIMESTAMP NOT NULL DEFAULT current_timestamp
);

CREATE TABLE IF NOT EXISTS artifacts (
    artifact_id   VARCHAR PRIMARY KEY,
    kind          VARCHAR NOT NULL,      -- manifest | raw_video | clip | shard | episode | checkpoint | ...
    uri           VARCHAR,               -- NULL for a span judged but never written
    sha256        VARCHAR,
    bytes         BIGINT,
    manifest_hash VARCHAR,
    stage_run_id  VARCHAR,               -- the stage run that produced it
    attrs         JSON,
    recorded_at   TIMESTAMP NOT NULL DEFAULT current_timestamp
);

CREATE TABLE IF NOT EXISTS edges (
    parent_id VARCHAR NOT NULL,
    child_id  VARCHAR NOT NULL,
    relation  VARCHAR NOT NULL,          -- derived | split_from | shard_of | trained_on | ...
    PRIMARY KEY (child_id, parent_id, relation)
);

CREATE TABLE IF NOT EXISTS metrics (
    subject_id    VARCHAR NOT NULL,      -- an artifact or a stage run
    name          VARCHAR NOT NULL,
    step          BIGINT NOT NULL DEFAULT 0,
    value         DOUBLE NOT NULL,
    stage_run_id  VARCHAR,
    manifest_hash VARCHAR,
    attrs         JSON,
    recorded_at   TIMESTAMP NOT NULL DEFAULT current_timestamp,
    PRIMARY KEY (subject_id, name, step)
);

CREATE TABLE IF NOT EXISTS rejections (
    artifact_id   VARCHAR NOT NULL,
    stage         VARCHAR NOT NULL,
    reason        VARCHAR NOT NULL,
    scores        JSON,
    detail        VARCHAR,
    stage_run_id  VARCHAR,
    manifest_hash VARCHAR,
    recorded_at   TIMESTAMP NOT NULL DEFAULT current_timestamp,
    PRIMARY KEY (artifact_id, stage)
);

-- The transitive closure of edges, kept by the writer (warehouse/closure.sql, a recursive CTE
-- over each batch's new edges) so that "everything behind this artifact" is one index lookup
-- instead of a walk whose every step scans all edges. Ancestor columns are copied from
-- artifacts at write time (a parent is always recorded before or with its child's edge).
CREATE TABLE IF NOT EXISTS ancestry (
    descendant_id     VARCHAR NOT NULL,
    ancestor_id       VARCHAR NOT NULL,
    depth             INTEGER NOT NULL,  -- shortest number of edges between them
    ancestor_kind     VARCHAR,
    ancestor_uri      VARCHAR,
    ancestor_sha256   VARCHAR,
    ancestor_manifest VARCHAR
);

CREATE INDEX IF NOT EXISTS ancestry_by_descendant ON ancestry (descendant_id);
CREATE INDEX IF NOT EXISTS rejections_by_manifest ON rejections (manifest_hash);
CREATE INDEX IF NOT EXISTS artifacts_by_manifest ON artifacts (manifest_hash);
