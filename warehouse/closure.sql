-- Extend the ancestry closure with one batch's new edges (the arrow table `batch_edges`).
-- Runs inside the writer's transaction, after the batch's artifacts and edges are inserted.
-- A new ancestor pair (d, a) is a path that uses at least one new edge c <- p: d is c or lies
-- below c, and a is p or lies above p through new edges or already-known closure rows.
CREATE OR REPLACE TEMP TABLE closure_fresh AS
WITH RECURSIVE up(start, ancestor, depth, via_closure) AS (
    SELECT child_id, parent_id, 1, false FROM batch_edges
    UNION
    SELECT u.start, step.parent, u.depth + step.depth, step.via_closure
    FROM up u
    JOIN (SELECT child_id AS child, parent_id AS parent, 1 AS depth, false AS via_closure FROM batch_edges
          UNION ALL
          SELECT descendant_id, ancestor_id, depth, true FROM ancestry) step
      ON step.child = u.ancestor
    -- the closure is transitive: two closure hops in a row only find what one hop finds
    WHERE u.depth < 64 AND NOT (u.via_closure AND step.via_closure)
),
spread AS (
    SELECT start AS descendant, ancestor, depth FROM up
    UNION ALL
    SELECT c.descendant_id, u.ancestor, c.depth + u.depth
    FROM ancestry c JOIN up u ON c.ancestor_id = u.start
)
SELECT descendant, ancestor, min(depth) AS depth FROM spread
WHERE descendant <> ancestor
GROUP BY descendant, ancestor;

-- A new path may be shorter than the one recorded: keep the shortest depth.
DELETE FROM ancestry USING closure_fresh f
WHERE ancestry.descendant_id = f.descendant AND ancestry.ancestor_id = f.ancestor AND f.depth < ancestry.depth;

INSERT INTO ancestry
SELECT f.descendant, f.ancestor, f.depth, a.kind, a.uri, a.sha256, a.manifest_hash
FROM closure_fresh f
LEFT JOIN artifacts a ON a.artifact_id = f.ancestor
WHERE NOT EXISTS (
    SELECT 1 FROM ancestry x WHERE x.descendant_id = f.descendant AND x.ancestor_id = f.ancestor
);

DROP TABLE closure_fresh;
