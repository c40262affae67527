"""Design studies: the predicted localisation error of candidate skin layouts and electrode placements (`neatskin design study`)."""
