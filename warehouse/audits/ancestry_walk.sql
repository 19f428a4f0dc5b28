-- The same ancestry as `ancestry`, found by walking the edges with a recursive CTE (slower; a cross-check).
-- params: artifact
WITH RECURSIVE walk(artifact_id, depth) AS (
    SELECT $artifact, 0
    UNION
    SELECT e.parent_id, w.depth + 1
    FROM edges e JOIN walk w ON e.child_id = w.artifact_id
    WHERE w.depth < 64
)
SELECT min(w.depth) AS depth, a.kind, w.artifact_id, a.uri, a.sha256, a.manifest_hash
FROM walk w
LEFT JOIN artifacts a ON a.artifact_id = w.artifact_id
WHERE w.depth > 0 OR a.artifact_id IS NOT NULL
GROUP BY ALL
ORDER BY depth, kind, artifact_id;
