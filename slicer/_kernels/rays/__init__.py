"""What the tracer and the renderer share: ray versus support, the walk's steps, lazy split points."""
