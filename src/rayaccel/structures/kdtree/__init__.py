"""kd-tree: SAH build by event sweep with perfect splits, flat layout, front-to-back traversal."""
