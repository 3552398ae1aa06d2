"""scene_builder package."""
