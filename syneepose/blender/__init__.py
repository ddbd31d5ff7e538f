"""The only bpy code of the project: build a Blender scene from a plain scene description, render
it with Cycles and hand back numpy arrays. Import its modules only inside render worker processes."""
