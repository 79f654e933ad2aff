//! cabc-learner: replay buffers, safety auto-labelling, constraint-aware training and the learner process.
