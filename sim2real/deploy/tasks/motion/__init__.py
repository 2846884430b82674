"""Reference motions (clips) as a command source: readers, the motion clock and the tracking task."""
