"""Thin DVC stage entry points: parse args, load params, call compact_perception, write outputs."""
