"""Image input: OpenImageIO reads, colour spaces (OCIO), UDIM sets, texel lookups with MaterialX's address modes and filters."""
