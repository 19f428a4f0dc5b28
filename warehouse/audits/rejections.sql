-- Rejections under one manifest, counted by stage and reason, with an example artifact each.
-- params: manifest
SELECT stage, reason, count(*) AS n, min(artifact_id) AS example_artifact
FROM rejections
WHERE manifest_hash = $manifest
GROUP BY stage, reason
ORDER BY n DESC, stage, reason;
