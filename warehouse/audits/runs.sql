-- Flow runs under one manifest with their status and how much work each stage did.
-- params: manifest
SELECT r.run_id, r.flow, r.status, r.started_at, r.ended_at, r.message,
       count(s.stage_run_id) AS stage_runs, coalesce(sum(s.n_out), 0) AS outputs
FROM runs r
LEFT JOIN stage_runs s USING (run_id)
WHERE r.manifest_hash = $manifest
GROUP BY ALL
ORDER BY r.started_at;
