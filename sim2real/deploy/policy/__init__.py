"""Policies as the runtime runs them: OnnxPolicy (feed-forward and recurrent; its spec, its graph),
the ONNX checks at load, our MLP checkpoint format (torch files read safely, the observation
normalizer), the gait prior inside a legged actor, and the adversarial policy.
"""
