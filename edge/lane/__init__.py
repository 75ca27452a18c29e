"""The lane profile's stages (spectra, peaks, pairs, angles, detections), one module each, and the records they pass
(:mod:`edge.lane.records`); :class:`edge.pipelines.lane.LanePipeline` runs them in order. See docs/lane-stages.md."""
