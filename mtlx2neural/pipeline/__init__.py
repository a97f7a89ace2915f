"""The per-material pipeline: plan, source hash, jobs and workers, output layout, lock, and convert_asset."""
