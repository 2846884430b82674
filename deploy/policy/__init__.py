"""Policies as the runtime runs them: OnnxPolicy (feed-forward and recurrent), the ONNX
checks at load, our MLP checkpoint format, the gait prior inside a legged actor, and the
adversarial policy.
"""
