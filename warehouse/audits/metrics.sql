-- Every metric recorded under one manifest, across runs, oldest first.
-- params: manifest
SELECT m.name, m.step, m.value, m.subject_id, s.stage, s.run_id, r.started_at AS run_started
FROM metrics m
LEFT JOIN stage_runs s USING (stage_run_id)
LEFT JOIN runs r ON r.run_id = s.run_id
WHERE m.manifest_hash = $manifest
ORDER BY m.name, run_started NULLS LAST, m.step;
