-- Worldline lineage warehouse, schema version 2. The only DDL in the project.
-- Each table is followed by the COMMENT ON text of it and its columns (added in version 2: a
-- migrated warehouse gets them from here, warehouse/store.py `comments`).
-- Every id is deterministic (a hash of what the row stands for), so re-runs insert nothing new.
CREATE TABLE IF NOT EXISTS worldline_meta (
    key   VARCHAR PRIMARY KEY,
    value VARCHAR NOT NULL
);
COMMENT ON TABLE worldline_meta IS 'Settings of this warehouse file. Key schema_version is the Worldline schema version that wrote it';
COMMENT ON COLUMN worldline_meta.key IS 'Setting name, e.g. schema_version';
COMMENT ON COLUMN worldline_meta.value IS 'Setting value, as text';

CREATE TABLE IF NOT EXISTS manifests (
    manifest_hash  VARCHAR PRIMARY KEY,   -- sha256 of the canonical JSON of its meaning
    name           VARCHAR NOT NULL,
    schema_version INTEGER NOT NULL,
    body           JSON NOT NULL,         -- the whole manifest, canonical JSON
    source_uri     VARCHAR,               -- the YAML file it was read from, if any
    parent_hash    VARCHAR,               -- the manifest it was derived from (the loop)
    recorded_at    TIMESTAMP NOT NULL DEFAULT current_timestamp
);
COMMENT ON TABLE manifests IS 'One row per scenario manifest recorded by any flow. A manifest''s artifact id is its hash, so every lineage walk ends here';
COMMENT ON COLUMN manifests.manifest_hash IS 'sha256 of the canonical JSON of the manifest''s meaning (its id everywhere)';
COMMENT ON COLUMN manifests.name IS 'Manifest name from its YAML';
COMMENT ON COLUMN manifests.schema_version IS 'Manifest schema version the body follows';
COMMENT ON COLUMN manifests.body IS 'The whole manifest as canonical JSON';
COMMENT ON COLUMN manifests.source_uri IS 'The YAML file it was read from, if any';
COMMENT ON COLUMN manifests.parent_hash IS 'manifest_hash of the manifest it was derived from (the improvement loop), else NULL';
COMMENT ON COLUMN manifests.recorded_at IS 'When this row was first written (UTC)';

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
COMMENT ON TABLE runs IS 'One row per flow run: what ran, under which manifest, and how it ended';
COMMENT ON COLUMN runs.run_id IS 'Run id: the Prefect flow run id when Prefect ran it, else a random UUID';
COMMENT ON COLUMN runs.flow IS 'Flow name: register, simulate, curate, tokenize, train, evaluate, ...';
COMMENT ON COLUMN runs.manifest_hash IS 'The manifest the run worked under (manifests.manifest_hash), if any';
COMMENT ON COLUMN runs.prefect_flow_run_id IS 'Prefect''s flow run id, NULL when it ran outside Prefect';
COMMENT ON COLUMN runs.status IS 'running, completed, partial (some inputs failed) or failed (interrupted included)';
COMMENT ON COLUMN runs.params IS 'The run''s parameters as JSON';
COMMENT ON COLUMN runs.message IS 'Why a run is partial or failed (failed inputs, the error, the signal)';
COMMENT ON COLUMN runs.started_at IS 'When the run started (UTC)';
COMMENT ON COLUMN runs.ended_at IS 'When the run ended (UTC), NULL while running or if its process died';

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
COMMENT ON TABLE stage_runs IS 'One row per stage over one input. A completed row is the marker a re-run skips on';
COMMENT ON COLUMN stage_runs.stage_run_id IS 'Hash of (stage, input_key): one row per unit of work';
COMMENT ON COLUMN stage_runs.run_id IS 'The run that did the work (runs.run_id)';
COMMENT ON COLUMN stage_runs.stage IS 'Stage name, e.g. decode, analyse, dedup, encode, shard';
COMMENT ON COLUMN stage_runs.input_key IS 'Hash of the stage''s inputs and config';
COMMENT ON COLUMN stage_runs.manifest_hash IS 'The manifest the stage worked under (manifests.manifest_hash)';
COMMENT ON COLUMN stage_runs.status IS 'completed, partial or failed';
COMMENT ON COLUMN stage_runs.n_in IS 'Number of inputs the stage read';
COMMENT ON COLUMN stage_runs.n_out IS 'Number of outputs the stage produced';
COMMENT ON COLUMN stage_runs.seconds IS 'Wall-clock seconds the stage took';
COMMENT ON COLUMN stage_runs.attrs IS 'Stage-specific details as JSON';
COMMENT ON COLUMN stage_runs.recorded_at IS 'When this row was first written (UTC)';

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
COMMENT ON TABLE artifacts IS 'One row per file written, or per span judged and not written. Ids are hashes of what they stand for';
COMMENT ON COLUMN artifacts.artifact_id IS 'Deterministic id of the artifact (a manifest''s is its hash)';
COMMENT ON COLUMN artifacts.kind IS 'manifest, raw_video, ground_truth, episode, episode_video, control, clip, shard, checkpoint, token_shard, panel, evaluation, report, ...';
COMMENT ON COLUMN artifacts.uri IS 'Path of the file relative to the data root, NULL for a span judged but never written';
COMMENT ON COLUMN artifacts.sha256 IS 'sha256 of the file''s bytes when it was recorded';
COMMENT ON COLUMN artifacts.bytes IS 'Size of the file in bytes';
COMMENT ON COLUMN artifacts.manifest_hash IS 'The manifest it was produced under (manifests.manifest_hash)';
COMMENT ON COLUMN artifacts.stage_run_id IS 'The stage run that produced it (stage_runs.stage_run_id)';
COMMENT ON COLUMN artifacts.attrs IS 'Kind-specific details as JSON (frames, fps, split, ...)';
COMMENT ON COLUMN artifacts.recorded_at IS 'When this row was first written (UTC)';

CREATE TABLE IF NOT EXISTS edges (
    parent_id VARCHAR NOT NULL,
    child_id  VARCHAR NOT NULL,
    relation  VARCHAR NOT NULL,          -- derived | split_from | shard_of | trained_on | ...
    PRIMARY KEY (child_id, parent_id, relation)
);
COMMENT ON TABLE edges IS 'One row per lineage edge: child_id was made from parent_id';
COMMENT ON COLUMN edges.parent_id IS 'The artifact (or manifest) the child was made from (artifacts.artifact_id)';
COMMENT ON COLUMN edges.child_id IS 'The artifact made from the parent (artifacts.artifact_id)';
COMMENT ON COLUMN edges.relation IS 'How: derived, split_from, shard_of, trained_on, ...';

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
COMMENT ON TABLE metrics IS 'One row per measurement of an artifact or a stage run, per step';
COMMENT ON COLUMN metrics.subject_id IS 'What was measured: an artifacts.artifact_id or a stage_runs.stage_run_id';
COMMENT ON COLUMN metrics.name IS 'Metric name, e.g. blur, loss, success_rate';
COMMENT ON COLUMN metrics.step IS 'Step of a series (training step, epoch), 0 for a single value';
COMMENT ON COLUMN metrics.value IS 'The measured value';
COMMENT ON COLUMN metrics.stage_run_id IS 'The stage run that measured it (stage_runs.stage_run_id)';
COMMENT ON COLUMN metrics.manifest_hash IS 'The manifest it was measured under (manifests.manifest_hash)';
COMMENT ON COLUMN metrics.attrs IS 'Details of the measurement as JSON';
COMMENT ON COLUMN metrics.recorded_at IS 'When this row was first written (UTC)';

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
COMMENT ON TABLE rejections IS 'One row per artifact rejected by a stage, with why';
COMMENT ON COLUMN rejections.artifact_id IS 'The rejected artifact (artifacts.artifact_id)';
COMMENT ON COLUMN rejections.stage IS 'The stage that rejected it, e.g. decode, dedup, motion, blur';
COMMENT ON COLUMN rejections.reason IS 'Short reason, e.g. unreadable, duplicate, static, blurry';
COMMENT ON COLUMN rejections.scores IS 'The scores the decision was made on, as a JSON map of name to number';
COMMENT ON COLUMN rejections.detail IS 'One line of detail, e.g. which artifact it duplicates';
COMMENT ON COLUMN rejections.stage_run_id IS 'The stage run that rejected it (stage_runs.stage_run_id)';
COMMENT ON COLUMN rejections.manifest_hash IS 'The manifest it was judged under (manifests.manifest_hash)';
COMMENT ON COLUMN rejections.recorded_at IS 'When this row was first written (UTC)';

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
COMMENT ON TABLE ancestry IS 'Transitive closure of edges, kept by the writer: one row per (descendant, ancestor) pair, so everything behind an artifact is one lookup';
COMMENT ON COLUMN ancestry.descendant_id IS 'The artifact whose ancestor this is (artifacts.artifact_id)';
COMMENT ON COLUMN ancestry.ancestor_id IS 'An artifact or manifest it was made from, directly or not';
COMMENT ON COLUMN ancestry.depth IS 'Shortest number of edges between them (1: a parent)';
COMMENT ON COLUMN ancestry.ancestor_kind IS 'The ancestor''s artifacts.kind, copied when the pair was written';
COMMENT ON COLUMN ancestry.ancestor_uri IS 'The ancestor''s artifacts.uri, copied when the pair was written';
COMMENT ON COLUMN ancestry.ancestor_sha256 IS 'The ancestor''s artifacts.sha256, copied when the pair was written';
COMMENT ON COLUMN ancestry.ancestor_manifest IS 'The ancestor''s artifacts.manifest_hash, copied when the pair was written';

CREATE INDEX IF NOT EXISTS ancestry_by_descendant ON ancestry (descendant_id);
CREATE INDEX IF NOT EXISTS rejections_by_manifest ON rejections (manifest_hash);
CREATE INDEX IF NOT EXISTS artifacts_by_manifest ON artifacts (manifest_hash);
