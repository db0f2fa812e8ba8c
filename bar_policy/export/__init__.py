"""Trained policy -> self-describing ONNX file, gated on numerical parity with the training framework.

``policy.export_policy`` writes the file (``policy`` documents the graph and the gate); ``graph`` builds
the ONNX model of an ``MlpPolicy``; ``parity`` compares onnxruntime with the framework's own inference.
"""
