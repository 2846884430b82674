"""The film strip: the moments of a soak worth watching, replayed from checkpoints and
rendered to clips (strip, render).
"""
