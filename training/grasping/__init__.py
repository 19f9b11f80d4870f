"""The planar grasp simulator of chapter 6 (objects, haptic controller, overhead camera) and its experiments."""
