"""Batches of takes: worker processes on this machine or a Dask farm, their progress and records."""
