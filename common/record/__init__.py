"""Recordings (MCAP): what a file holds (:mod:`common.record.info`)."""
