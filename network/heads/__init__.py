"""Small heads on the frozen network that read metric depths: the boards' back edges, the rear
uprights (both give the rack depth) and each box's depth."""
