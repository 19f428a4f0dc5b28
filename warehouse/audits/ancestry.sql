-- The full ancestry of one artifact: every parent, grandparent, ... back to raw videos and manifests.
-- params: artifact
WITH RECURSIVE ancestry(artifact_id, depth) AS (
    SELECT $artifact, 0
    UNION
    SELECT e.parent_id, a.depth + 1
    FROM edges e JOIN ancestry a ON e.child_id = a.artifact_id
    WHERE a.depth < 64
)
SELECT min(x.depth) AS depth, art.kind, x.artifact_id, art.uri, art.sha256, art.manifest_hash, m.name AS manifest_name
FROM ancestry x
LEFT JOIN artifacts art ON art.artifact_id = x.artifact_id
LEFT JOIN manifests m ON m.manifest_hash = coalesce(art.manifest_hash, x.artifact_id)
GROUP BY ALL
ORDER BY depth, kind, x.artifact_id;
