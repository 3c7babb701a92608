"""Stock behaviour-tree leaves (filled in by the tree builder module)."""
