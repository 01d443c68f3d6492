"""``cirl-study serve``: the web experiment that collects people's demonstrations.

A pipeline with ``[participants] collect = true`` and an ``[experiment]`` table
(:class:`~cirl_study.study.spec.ExperimentSpec`) runs as a web experiment: each participant
agrees to the consent, reads her condition's instructions, plays the practice task and then
her tasks in a counterbalanced order (:mod:`~cirl_study.serve.assignment`), on a page of this
package (``page/``) that moves by keyboard, click or touch. Her sessions are files of the run
directory (:mod:`~cirl_study.serve.sessions`); each demonstration is checked on the server and
stored durably (:mod:`cirl_study.logs.collection`) before the page is told
(:mod:`~cirl_study.serve.experiment`), over HTTP (:mod:`~cirl_study.serve.app`), by a server
that holds the run directory's lock while it runs (:mod:`~cirl_study.serve.server`).
"""
