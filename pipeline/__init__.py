"""Running envfuse: the CLI, fusing walks, evaluating many, reports and plots."""
