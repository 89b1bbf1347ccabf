"""From pixels to the board: frames (Appendix B, homographies) and grounding (Appendix C)."""
