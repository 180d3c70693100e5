"""Pictures for reports: one module per topic (renders, skeletons, poses, scenes)."""
