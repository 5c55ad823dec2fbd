"""Action planning: IK, candidates, checks, visibility, selection."""
