"""The layer viewer: one self-contained HTML page."""
