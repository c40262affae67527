"""Campaigns: protocol files, scenes, and the runner (real rig or dry run)."""
