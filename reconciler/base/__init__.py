"""The foundations every layer stands on: errors, safe text, atomic writes, the layout of
paths, bounded reading, YAML loading. None of them imports lpam above."""
