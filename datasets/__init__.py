"""datasets: loaders for the real file formats of depth-from-defocus datasets, and focus synthesis.

Not Hugging Face's ``datasets``: never install that package in this environment.
"""
