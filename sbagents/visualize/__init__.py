"""What a person looks at: learning curves (:mod:`~sbagents.visualize.curves`), videos
(:mod:`~sbagents.visualize.video`), text episodes (:mod:`~sbagents.visualize.text_render`) and the learned path
(:mod:`~sbagents.visualize.showcase`)."""
