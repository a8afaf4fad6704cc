"""The segmenter: a 4D scene -> time nodes -> spatial chunks under a pixel budget -> container."""
