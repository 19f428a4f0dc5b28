-- Behind one evaluation: its failed cells, then the panel, checkpoints, training shards, clips, raw videos and manifests; and what the loop made of it: derived manifests, their demonstrations, the post-trained policy, its evaluation.
-- params: artifact
-- `artifact` is an evaluation id (kind 'evaluation'). A cell failed when its simulator success
-- rate is below the evaluated manifest's evaluation.min_success_rate (0.8 when unset). What is
-- behind it is the evaluation's ancestry from the closure the writer keeps (audits/ancestry.sql),
-- kept to the kinds a failure is traced through, nearest first. What followed is its descendants
-- in the same closure: the manifests `worldline loop` derived from its failed cells (a
-- 'derived_from_failure' edge from the evaluation), the episodes simulated from them (the
-- demonstrations), the checkpoint post-trained on those ('trained_on'), and that checkpoint's
-- evaluation; their kinds are prefixed 'then_'.
WITH evaluation AS (
    SELECT artifact_id, manifest_hash FROM artifacts WHERE artifact_id = $artifact AND kind = 'evaluation'
),
bar AS (
    SELECT coalesce(TRY_CAST(json_extract_string(m.body, '$.evaluation.min_success_rate') AS DOUBLE), 0.8) AS bar
    FROM evaluation e LEFT JOIN manifests m ON m.manifest_hash = e.manifest_hash
),
failed AS (
    SELECT 0 AS depth, 'failed_cell' AS kind, replace(mt.name, 'sim_success_rate/', '') AS id,
           NULL::VARCHAR AS uri, mt.value AS success_rate, e.manifest_hash
    FROM evaluation e JOIN metrics mt ON mt.subject_id = e.artifact_id, bar
    WHERE mt.name LIKE 'sim_success_rate/%' AND mt.value < bar.bar
),
behind AS (
    SELECT a.depth, a.ancestor_kind AS kind, a.ancestor_id AS id, a.ancestor_uri AS uri,
           NULL::DOUBLE AS success_rate, a.ancestor_manifest AS manifest_hash
    FROM evaluation e JOIN ancestry a ON a.descendant_id = e.artifact_id
    WHERE a.ancestor_kind IN ('panel', 'checkpoint', 'token_shard', 'shard', 'clip', 'raw_video', 'episode_video',
                              'episode', 'manifest')
),
followed AS (
    SELECT a.depth, 'then_' || coalesce(d.kind, 'manifest') AS kind, a.descendant_id AS id, d.uri,
           NULL::DOUBLE AS success_rate, coalesce(d.manifest_hash, a.descendant_id) AS manifest_hash
    FROM evaluation e JOIN ancestry a ON a.ancestor_id = e.artifact_id
    LEFT JOIN artifacts d ON d.artifact_id = a.descendant_id
    WHERE coalesce(d.kind, 'manifest') IN ('manifest', 'episode', 'checkpoint', 'evaluation')
      AND coalesce(d.attrs->>'role', '') <> 'comparison'  -- the side-by-side summaries of evaluations
)
SELECT f.depth, f.kind, f.id, f.uri, f.success_rate, f.manifest_hash, m.name AS manifest_name
FROM (SELECT * FROM failed UNION ALL SELECT * FROM behind UNION ALL SELECT * FROM followed) f
LEFT JOIN manifests m ON m.manifest_hash = f.manifest_hash
ORDER BY CASE f.kind WHEN 'failed_cell' THEN 0 WHEN 'panel' THEN 1 WHEN 'checkpoint' THEN 2 WHEN 'token_shard' THEN 3
                     WHEN 'shard' THEN 4 WHEN 'clip' THEN 5 WHEN 'raw_video' THEN 6 WHEN 'episode_video' THEN 6
                     WHEN 'episode' THEN 7 WHEN 'manifest' THEN 8 WHEN 'then_manifest' THEN 9 WHEN 'then_episode' THEN 10
                     WHEN 'then_checkpoint' THEN 11 WHEN 'then_evaluation' THEN 12 ELSE 13 END, f.depth, f.id;
