"""Shape completion (paper Sec. III-A): branch completion, free space, DeepSDF, SSC, baselines, metrics."""
