"""Profile pipelines (built by :func:`edge.pipeline.build_pipeline`)."""
