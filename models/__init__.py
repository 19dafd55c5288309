"""models: depth networks, losses, metrics and self-supervised training through the renderer."""
