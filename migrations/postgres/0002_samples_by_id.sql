-- Lineage by sample id alone (`vintctl lineage SAMPLE` without --job) finds the newest job that
-- packaged it in one indexed lookup.
CREATE INDEX samples_by_sample_id ON samples (sample_id);
