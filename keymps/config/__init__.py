"""Task files: the pydantic models, YAML with positions, command-line overrides, resource bounds."""
