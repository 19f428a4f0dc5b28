-- The full ancestry of one artifact: every parent, grandparent, ... back to raw videos and manifests.
-- params: artifact
-- Reads the closure the writer keeps (warehouse/closure.sql, a recursive CTE run per batch);
-- audits/ancestry_walk.sql walks the edges at query time instead and must agree with it.
WITH found AS (
    SELECT 0 AS depth, kind, artifact_id, uri, sha256, manifest_hash
    FROM artifacts WHERE artifact_id = $artifact
    UNION ALL
    SELECT depth, ancestor_kind, ancestor_id, ancestor_uri, ancestor_sha256, ancestor_manifest
    FROM ancestry WHERE descendant_id = $artifact
)
SELECT f.*, m.name AS manifest_name
FROM found f LEFT JOIN manifests m ON m.manifest_hash = f.manifest_hash
ORDER BY f.depth, f.kind, f.artifact_id;
