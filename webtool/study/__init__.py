"""The study page: the evaluation reports of the data folder, and a study started from the
page.

``routes`` (the JSON API and the report files), ``service`` (the reports and the running study).
"""

from webtool.study.service import StudyService

__all__ = ["StudyService"]
