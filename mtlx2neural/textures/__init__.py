"""textures stage: texture input, colour, parameter maps, LEAN pyramid, footprint sampling."""
