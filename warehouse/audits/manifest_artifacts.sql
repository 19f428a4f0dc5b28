-- Every artifact recorded under one manifest, by kind, with the stage run that made it.
-- params: manifest
SELECT a.kind, a.artifact_id, a.uri, a.sha256, a.bytes, s.stage, a.recorded_at
FROM artifacts a
LEFT JOIN stage_runs s USING (stage_run_id)
WHERE a.manifest_hash = $manifest
ORDER BY a.kind, a.uri NULLS LAST, a.artifact_id;
