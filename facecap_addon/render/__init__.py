"""Pictures rendered by Blender: the review page's contact sheet, the docs' pictures, footage of a face."""
